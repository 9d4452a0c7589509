"""Measured material tables (``NAME.csv`` beside a ``NAME.json`` sidecar): core loss or complex
permeability over frequency x peak flux density, as the vendored real data of ``tests/data/real/``.

Two layouts, told apart by the header:

* core loss: ``frequency_Hz,flux_density_peak_T,loss_W_per_m3`` (time-averaged loss per volume
  under a sinusoidal flux density of that peak), or with MagNet's four duty fractions before the
  loss, ``frequency_Hz,flux_density_peak_T,duty_1,duty_2,duty_3,duty_4,loss_W_per_m3``, for a
  triangular/trapezoidal B(t) (:mod:`~hystbench.formats.flux_shapes` rebuilds it; a row with all
  four ``-1`` is a sine, MagNet's convention);
* complex permeability: ``frequency_Hz,flux_density_peak_T,mu_real,mu_imag`` (relative, with
  ``mu_imag <= 0`` for a lossy material: mu_r = mu' - j mu'').

The sidecar says where the numbers came from; a table whose source, licence or units are unknown
cannot be quoted, so those keys are required.  Reading is strict as for recordings: every defect is
a :class:`RecordingError` naming the file, line and column; nothing is dropped or guessed.  A table
is read whole, so its size is bounded first (:data:`~hystbench.formats.small_files.MAX_TABLE_BYTES`,
the sidecar's by ``MAX_SIDECAR_BYTES``).
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import RecordingError
from .small_files import MAX_TABLE_BYTES, excerpt, read_json, read_text

__all__ = ["DUTY_COLUMNS", "LossTable", "LAYOUTS", "REQUIRED_SIDECAR_KEYS", "read_material_table"]

#: Column layouts by kind (the sidecar's ``kind`` must match the header's).
LAYOUTS = {
    "core_loss": ("frequency_Hz", "flux_density_peak_T", "loss_W_per_m3"),
    "complex_permeability": ("frequency_Hz", "flux_density_peak_T", "mu_real", "mu_imag"),
}

#: MagNet's duty fractions, optional in a core-loss table (between the flux density and the loss).
DUTY_COLUMNS = ("duty_1", "duty_2", "duty_3", "duty_4")

#: Sidecar keys every table must have.
REQUIRED_SIDECAR_KEYS = ("material", "kind", "source", "licence", "units", "core_shape", "temperature_C", "trimmed")

_NUMBER = re.compile(r"\s*[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?\s*", re.A)  # finite decimals only
_POSITIVE = ("frequency_Hz", "flux_density_peak_T")
_DUTY_SUM_TOL = 1e-9  # MagNet's tenths in float64 sum to 1 within 2e-16


@dataclass(frozen=True, eq=False)
class LossTable:
    """One material table: the columns as float64 arrays (file order) and the whole sidecar."""

    path: Path
    kind: str
    columns: dict[str, np.ndarray]
    metadata: dict

    @property
    def material(self) -> str:
        return str(self.metadata["material"])

    @property
    def frequency_hz(self) -> np.ndarray:
        return self.columns["frequency_Hz"]

    @property
    def flux_density_t(self) -> np.ndarray:
        return self.columns["flux_density_peak_T"]

    @property
    def duty(self) -> np.ndarray:
        """(rows, 4) MagNet duty fractions; all -1 (a sine) for a table without duty columns."""
        if DUTY_COLUMNS[0] not in self.columns:
            return np.full((len(self), 4), -1.0)
        return np.column_stack([self.columns[c] for c in DUTY_COLUMNS])

    def __len__(self) -> int:
        return int(self.frequency_hz.size)


def read_material_table(path: str | Path) -> LossTable:
    """Read ``path`` (the ``.csv``; the sidecar is the same stem's ``.json``)."""
    csv_path = Path(path).with_suffix(".csv")
    meta = _read_sidecar(csv_path.with_suffix(".json"))
    kind = meta["kind"]
    names, data = _read_rows(csv_path, _layouts(kind), kind)
    units = meta["units"]
    if not isinstance(units, dict) or sorted(units) != sorted(names):
        raise RecordingError(f"{csv_path.with_suffix('.json')}: key 'units' must give the unit of every column "
                             f"({', '.join(names)}), got {units!r}")
    _check_values(csv_path, names, data)
    return LossTable(csv_path, kind, {n: data[:, j].copy() for j, n in enumerate(names)}, meta)


def _read_sidecar(path: Path) -> dict:
    if not path.is_file():
        raise RecordingError(f"{path}: missing sidecar (a material table needs its source, licence and units)")
    meta = read_json(path)
    if not isinstance(meta, dict):
        raise RecordingError(f"{path}: the sidecar must be a JSON object, got {type(meta).__name__}")
    for key in REQUIRED_SIDECAR_KEYS:
        if key not in meta:
            raise RecordingError(f"{path}: missing key {key!r} (required: {', '.join(REQUIRED_SIDECAR_KEYS)})")
    if meta["kind"] not in LAYOUTS:
        raise RecordingError(f"{path}: key 'kind' must be one of {', '.join(LAYOUTS)}, got {meta['kind']!r}")
    if not isinstance(meta["material"], str) or not meta["material"]:
        raise RecordingError(f"{path}: key 'material' must be a non-empty string, got {meta['material']!r}")
    return meta


def _layouts(kind: str) -> tuple[tuple[str, ...], ...]:
    """The headers a ``kind`` may have: its layout, and for core loss the same with the duties."""
    base = LAYOUTS[kind]
    return (base, base[:2] + DUTY_COLUMNS + base[2:]) if kind == "core_loss" else (base,)


def _read_rows(path: Path, layouts: tuple[tuple[str, ...], ...], kind: str) -> tuple[list[str], np.ndarray]:
    """The header (one of ``layouts``) and the (rows, columns) array."""
    lines = read_text(path, MAX_TABLE_BYTES, "material table", "MAX_TABLE_BYTES").rstrip("\n").split("\n")
    names = [n.strip() for n in lines[0].split(",")]
    if tuple(names) not in layouts:
        raise RecordingError(f"{path}:1: header {excerpt(lines[0].strip(), 120)} is not the {kind} layout "
                             f"{' or '.join(repr(','.join(x)) for x in layouts)} its sidecar declares")
    if len(lines) < 2:
        raise RecordingError(f"{path}: no rows after the header")
    try:  # the fast path; the loop below runs only to name a defect
        data = np.array([[float(x) for x in line.split(",")] for line in lines[1:]], dtype=np.float64)
        ok = data.ndim == 2 and data.shape[1] == len(names) and all(_NUMBER.fullmatch(x) for x in ",".join(lines[1:]).split(","))
    except ValueError:
        ok = False
    if not ok:
        for lineno, line in enumerate(lines[1:], start=2):
            fields = line.split(",")
            if len(fields) != len(names):
                raise RecordingError(f"{path}:{lineno}: {len(fields)} fields, the header has {len(names)}")
            for j, field in enumerate(fields):
                if not _NUMBER.fullmatch(field):
                    what = "empty field" if not field.strip() else f"{excerpt(field.strip())} is not a finite number"
                    raise RecordingError(f"{path}:{lineno}: column {j + 1} ({names[j]}): {what}")
    return names, data


def _check_values(path: Path, names: list[str], data: np.ndarray) -> None:
    """Physical signs: frequency and peak flux density > 0, loss >= 0, mu' > 0, mu'' >= 0; duties
    fractions in [0, 1] summing to 1, or all four -1 (a sine)."""
    if DUTY_COLUMNS[0] in names:
        _check_duties(path, names, data)
    rules = {n: (lambda c: c > 0, "must be > 0") for n in _POSITIVE}
    rules["loss_W_per_m3"] = (lambda c: c >= 0, "must be >= 0 (a negative loss would be a core giving energy)")
    rules["mu_real"] = (lambda c: c > 0, "must be > 0")
    rules["mu_imag"] = (lambda c: c <= 0, "must be <= 0 (mu_r = mu' - j mu''; mu'' < 0 would be a core giving energy)")
    for j, name in enumerate(names):
        if name in DUTY_COLUMNS:
            continue  # checked together, by row, above
        good, why = rules[name]
        bad = ~good(data[:, j])
        if bad.any():
            r = int(np.argmax(bad))
            raise RecordingError(f"{path}:{r + 2}: column {j + 1} ({name}): {float(data[r, j])!r} {why}")


def _check_duties(path: Path, names: list[str], data: np.ndarray) -> None:
    j = names.index(DUTY_COLUMNS[0])
    duty = data[:, j:j + 4]
    sine = np.all(duty == -1.0, axis=1)
    bad_value = ~sine[:, None] & ((duty < 0) | (duty > 1))
    if bad_value.any():
        r, k = (int(x) for x in np.argwhere(bad_value)[0])
        raise RecordingError(f"{path}:{r + 2}: column {j + k + 1} ({DUTY_COLUMNS[k]}): {float(duty[r, k])!r} must be "
                             "a fraction in [0, 1] (or all four -1 for a sine)")
    bad_sum = ~sine & (np.abs(duty.sum(axis=1) - 1.0) > _DUTY_SUM_TOL)
    if bad_sum.any():
        r = int(np.argmax(bad_sum))
        raise RecordingError(f"{path}:{r + 2}: columns {j + 1}-{j + 4} (duty_1..duty_4): {duty[r].tolist()} sum to "
                             f"{float(duty[r].sum())!r}, not 1 (the four fractions of one period)")
