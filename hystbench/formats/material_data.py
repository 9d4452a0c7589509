"""Measured material tables (``NAME.csv`` beside a ``NAME.json`` sidecar): core loss or complex
permeability over frequency x peak flux density, as the vendored real data of ``tests/data/real/``.

Two layouts, told apart by the header:

* core loss: ``frequency_Hz,flux_density_peak_T,loss_W_per_m3`` (time-averaged loss per volume
  under a sinusoidal flux density of that peak);
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

__all__ = ["LossTable", "LAYOUTS", "REQUIRED_SIDECAR_KEYS", "read_material_table"]

#: Column layouts by kind (the sidecar's ``kind`` must match the header's).
LAYOUTS = {
    "core_loss": ("frequency_Hz", "flux_density_peak_T", "loss_W_per_m3"),
    "complex_permeability": ("frequency_Hz", "flux_density_peak_T", "mu_real", "mu_imag"),
}

#: Sidecar keys every table must have.
REQUIRED_SIDECAR_KEYS = ("material", "kind", "source", "licence", "units", "core_shape", "temperature_C", "trimmed")

_NUMBER = re.compile(r"\s*[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?\s*", re.A)  # finite decimals only
_POSITIVE = ("frequency_Hz", "flux_density_peak_T")


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

    def __len__(self) -> int:
        return int(self.frequency_hz.size)


def read_material_table(path: str | Path) -> LossTable:
    """Read ``path`` (the ``.csv``; the sidecar is the same stem's ``.json``)."""
    csv_path = Path(path).with_suffix(".csv")
    meta = _read_sidecar(csv_path.with_suffix(".json"))
    kind = meta["kind"]
    names, data = _read_rows(csv_path, LAYOUTS[kind], kind)
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


def _read_rows(path: Path, layout: tuple[str, ...], kind: str) -> tuple[list[str], np.ndarray]:
    """The header (checked against ``layout``) and the (rows, columns) array."""
    lines = read_text(path, MAX_TABLE_BYTES, "material table", "MAX_TABLE_BYTES").rstrip("\n").split("\n")
    names = [n.strip() for n in lines[0].split(",")]
    if tuple(names) != layout:
        raise RecordingError(f"{path}:1: header {excerpt(lines[0].strip(), 120)} is not the {kind} layout "
                             f"{','.join(layout)!r} its sidecar declares")
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
    """Physical signs: frequency and peak flux density > 0, loss >= 0, mu' > 0, mu'' >= 0."""
    rules = {n: (lambda c: c > 0, "must be > 0") for n in _POSITIVE}
    rules["loss_W_per_m3"] = (lambda c: c >= 0, "must be >= 0 (a negative loss would be a core giving energy)")
    rules["mu_real"] = (lambda c: c > 0, "must be > 0")
    rules["mu_imag"] = (lambda c: c <= 0, "must be <= 0 (mu_r = mu' - j mu''; mu'' < 0 would be a core giving energy)")
    for j, name in enumerate(names):
        good, why = rules[name]
        bad = ~good(data[:, j])
        if bad.any():
            r = int(np.argmax(bad))
            raise RecordingError(f"{path}:{r + 2}: column {j + 1} ({name}): {float(data[r, j])!r} {why}")
