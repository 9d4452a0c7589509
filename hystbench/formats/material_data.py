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

Measured waveforms (rows of B(t), maybe H(t), with frequency, temperature, loss or material, as
mag-net-hub's test files) are read by :func:`read_waveform_table`.

The sidecar says where the numbers came from; a table whose source, licence or units are unknown
cannot be quoted, so those keys are required.  Reading is strict as for recordings: every defect is
a :class:`RecordingError` naming the file, line and column; nothing is dropped or guessed.  A table
is read whole, so its size is bounded first (:data:`~hystbench.formats.small_files.MAX_TABLE_BYTES`,
the sidecar's by ``MAX_SIDECAR_BYTES``).
"""

from __future__ import annotations

import math
import os
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import RecordingError
from .small_files import MAX_TABLE_BYTES, excerpt, finite, read_json, read_text, shown

__all__ = ["COLUMN_UNITS", "DUTY_COLUMNS", "LossTable", "LAYOUTS", "REQUIRED_SIDECAR_KEYS", "REQUIRED_WAVEFORM_KEYS",
           "WAVEFORM_COLUMNS", "WaveformTable", "read_material_table", "read_waveform_table"]

#: Column layouts by kind (the sidecar's ``kind`` must match the header's).
LAYOUTS = {
    "core_loss": ("frequency_Hz", "flux_density_peak_T", "loss_W_per_m3"),
    "complex_permeability": ("frequency_Hz", "flux_density_peak_T", "mu_real", "mu_imag"),
}

#: MagNet's duty fractions, optional in a core-loss table (between the flux density and the loss).
DUTY_COLUMNS = ("duty_1", "duty_2", "duty_3", "duty_4")

#: The unit of every column a material table may have, as its sidecar must give it.
COLUMN_UNITS = {"frequency_Hz": "Hz", "flux_density_peak_T": "T", "loss_W_per_m3": "W/m^3", "mu_real": "1",
                "mu_imag": "1", **{c: "1" for c in DUTY_COLUMNS}}

#: Sidecar keys every table must have.
REQUIRED_SIDECAR_KEYS = ("material", "kind", "source", "licence", "units", "core_shape", "temperature_C", "trimmed")

_NUMBER = re.compile(r"\s*[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?\s*", re.A)  # finite decimals only
_POSITIVE = ("frequency_Hz", "flux_density_peak_T")
MAX_FLUX_DENSITY_T = 5.0  # twice the highest saturation of any magnetic material (FeCo, 2.45 T)
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


def _table_paths(path: str | Path) -> tuple[Path, Path]:
    """The table's ``.csv`` (as given, ``N87.CSV`` too) and its sidecar, the same stem's ``.json``
    (or ``.JSON`` when only that one is there)."""
    path = Path(path)
    csv_path = path if path.suffix.lower() == ".csv" else path.with_suffix(".csv")
    side = csv_path.with_suffix(".json")
    if not os.path.lexists(side) and os.path.lexists(csv_path.with_suffix(".JSON")):
        side = csv_path.with_suffix(".JSON")
    return csv_path, side


def read_material_table(path: str | Path) -> LossTable:
    """Read ``path`` (the ``.csv``; the sidecar is the same stem's ``.json``)."""
    csv_path, side = _table_paths(path)
    meta = _read_sidecar(side)
    kind = meta["kind"]
    names, data = _read_rows(csv_path, _layouts(kind), kind)
    units = meta["units"]
    if not isinstance(units, dict) or sorted(units) != sorted(names):
        raise RecordingError(f"{side}: key 'units' must give the unit of every column ({', '.join(names)}), "
                             f"got {units!r}")
    for name in names:  # the header names the unit too: a sidecar that says otherwise is a table in other units
        if units[name] != COLUMN_UNITS[name]:
            raise RecordingError(f"{side}: key 'units': {name} is in {units[name]!r}; this reader takes "
                                 f"{COLUMN_UNITS[name]!r} (convert the column)")
    _check_values(csv_path, names, data)
    return LossTable(csv_path, kind, {n: data[:, j].copy() for j, n in enumerate(names)}, meta)


def _sidecar_with(path: Path, what: str, required: tuple[str, ...]) -> dict:
    """The JSON object of a table's sidecar, with every ``required`` key, or an error naming the file."""
    if not os.path.lexists(path):
        raise RecordingError(f"{path}: missing sidecar (a {what} needs its source, licence and units)")
    meta = read_json(path)
    if not isinstance(meta, dict):
        raise RecordingError(f"{path}: the sidecar must be a JSON object, got {type(meta).__name__}")
    for key in required:
        if key not in meta:
            raise RecordingError(f"{path}: missing key {key!r} (required: {', '.join(required)})")
    return meta


def _read_sidecar(path: Path) -> dict:
    meta = _sidecar_with(path, "material table", REQUIRED_SIDECAR_KEYS)
    if not isinstance(meta["kind"], str) or meta["kind"] not in LAYOUTS:
        raise RecordingError(f"{path}: key 'kind' must be one of {', '.join(LAYOUTS)}, got {meta['kind']!r}")
    if not isinstance(meta["material"], str) or not meta["material"].strip():
        raise RecordingError(f"{path}: key 'material' must be a non-empty string, got {meta['material']!r}")
    if meta["material"] != meta["material"].strip():  # 'N87 ' would keep a table apart from N87's others
        raise RecordingError(f"{path}: key 'material' {meta['material']!r} has spaces around it; tables of one "
                             "material are diagnosed together by its name")
    t = meta["temperature_C"]
    if isinstance(t, bool) or not isinstance(t, (int, float)) or not (finite(t) and t > -273.15):
        raise RecordingError(f"{path}: key 'temperature_C' must be the measurement's temperature in degC (a number "
                             f"above -273.15), got {shown(t)}")
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
        ok = (data.ndim == 2 and data.shape[1] == len(names) and bool(np.all(np.isfinite(data)))
              and all(_NUMBER.fullmatch(x) for x in ",".join(lines[1:]).split(",")))
    except ValueError:
        ok = False
    if not ok:
        for lineno, line in enumerate(lines[1:], start=2):
            fields = line.split(",")
            if len(fields) != len(names):
                raise RecordingError(f"{path}:{lineno}: {len(fields)} fields, the header has {len(names)}")
            for j, field in enumerate(fields):
                if not _NUMBER.fullmatch(field) or not np.isfinite(float(field)):  # 1e999 reads as inf
                    what = "empty field" if not field.strip() else f"{excerpt(field.strip())} is not a finite number"
                    raise RecordingError(f"{path}:{lineno}: column {j + 1} ({names[j]}): {what}")
    return names, data


def _check_values(path: Path, names: list[str], data: np.ndarray) -> None:
    """Physical signs: frequency > 0, peak flux density in (0, 5 T], loss >= 0, mu' > 0, mu'' >= 0; duties
    fractions in [0, 1] summing to 1, or all four -1 (a sine)."""
    if DUTY_COLUMNS[0] in names:
        _check_duties(path, names, data)
    rules = {n: (lambda c: c > 0, "must be > 0") for n in _POSITIVE}
    rules["flux_density_peak_T"] = (lambda c: (c > 0) & (c <= MAX_FLUX_DENSITY_T),
                                    f"must be > 0 and <= {MAX_FLUX_DENSITY_T:g} T (no iron saturates above 2.5 T: "
                                    "a column in mT?)")
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
    # what formats.flux_shapes rebuilds: a rise and a fall (a step in B has no dB/dt to integrate), and
    # MagNet's trapezoids' equal flat segments
    no_ramp = ~sine & ((duty[:, 0] <= 0) | (duty[:, 2] <= 0))
    if no_ramp.any():
        r = int(np.argmax(no_ramp))
        k = 0 if duty[r, 0] <= 0 else 2
        raise RecordingError(f"{path}:{r + 2}: column {j + k + 1} ({DUTY_COLUMNS[k]}): {float(duty[r, k])!r}; "
                             "the rise (duty_1) and the fall (duty_3) of a triangle or trapezoid take time (> 0)")
    uneven = ~sine & (np.abs(duty[:, 1] - duty[:, 3]) > _DUTY_SUM_TOL)
    if uneven.any():
        r = int(np.argmax(uneven))
        raise RecordingError(f"{path}:{r + 2}: columns {j + 2} and {j + 4} (duty_2, duty_4): {float(duty[r, 1])!r} and "
                             f"{float(duty[r, 3])!r}; MagNet's trapezoids have equal flat segments, another waveform "
                             "is not rebuilt")


# --- measured waveforms ------------------------------------------------------------------------

#: The columns a waveform table may have beside its samples, as mag-net-hub names them: the
#: :class:`WaveformTable` field each fills and the unit its sidecar must give (None: a name).
WAVEFORM_COLUMNS = {"freq": ("frequency_hz", "Hz"), "temp": ("temperature_c", "degC"),
                    "ploss": ("loss_w_per_m3", "W/m^3"), "material": ("material", None)}
#: Sidecar keys every waveform table must have (``material`` too when the file has no such column).
REQUIRED_WAVEFORM_KEYS = ("kind", "source", "licence", "units", "row")
_MATERIAL = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.+-]*", re.A)


@dataclass(frozen=True, eq=False)
class WaveformTable:
    """Rows of one measured waveform each: B(t) (and H(t) when the file has it) with the row's
    frequency, temperature and loss when the file has them (else None), and its material (the
    file's column, else the sidecar's).  Samples are (rows, samples) float64 arrays, SI units."""

    path: Path
    b_t: np.ndarray
    h_t: np.ndarray | None
    frequency_hz: np.ndarray | None
    temperature_c: np.ndarray | None
    loss_w_per_m3: np.ndarray | None
    material: tuple[str, ...]
    metadata: dict

    @property
    def samples(self) -> int:
        return int(self.b_t.shape[1])

    def __len__(self) -> int:
        return int(self.b_t.shape[0])


def read_waveform_table(path: str | Path) -> WaveformTable:
    """Read ``path`` (the ``.csv``; the sidecar is the same stem's ``.json``, ``kind: waveform``).

    The header is ``B_t_0..B_t_{n-1}``, optionally ``H_t_0..H_t_{n-1}``, then any of
    :data:`WAVEFORM_COLUMNS`; the sidecar's ``units`` gives ``B_t_*``, ``H_t_*`` and each scalar
    column its unit, which must be the one the fields are named for (a file in kHz or mT would
    otherwise be read a thousand times off).  Strict as :func:`read_material_table`.
    """
    csv_path, side = _table_paths(path)
    meta = _read_waveform_sidecar(side)
    lines = read_text(csv_path, MAX_TABLE_BYTES, "waveform table", "MAX_TABLE_BYTES").rstrip("\n").split("\n")
    names = [n.strip() for n in lines[0].split(",")]
    n, has_h, scalars = _waveform_header(csv_path, names)
    if "material" not in scalars and not (isinstance(meta.get("material"), str) and meta["material"]):
        raise RecordingError(f"{side}: missing key 'material' (a non-empty string: the file has no material column)")
    want = {"B_t_*": "T", **({"H_t_*": "A/m"} if has_h else {}),
            **{c: WAVEFORM_COLUMNS[c][1] for c in scalars if c != "material"}}
    units = meta["units"]
    if not isinstance(units, dict) or sorted(units) != sorted(want):
        raise RecordingError(f"{side}: key 'units' must give the unit of every column ({', '.join(want)}), "
                             f"got {units!r}")
    for key, unit in want.items():
        if units[key] != unit:
            raise RecordingError(f"{side}: key 'units': {key} is in {units[key]!r}; this reader takes {unit!r}")
    if len(lines) < 2:
        raise RecordingError(f"{csv_path}: no rows after the header")
    numeric = [j for j, name in enumerate(names) if name != "material"]
    m = names.index("material") if "material" in scalars else None
    values = np.empty((len(lines) - 1, len(numeric)))
    materials: list[str] = []
    for r, line in enumerate(lines[1:]):
        fields = line.split(",")
        if len(fields) != len(names):
            raise RecordingError(f"{csv_path}:{r + 2}: {len(fields)} fields, the header has {len(names)}")
        for k, j in enumerate(numeric):
            if not _NUMBER.fullmatch(fields[j]):
                field = fields[j].strip()
                what = "empty field" if not field else f"{excerpt(field)} is not a finite number"
                raise RecordingError(f"{csv_path}:{r + 2}: column {j + 1} ({names[j]}): {what}")
            values[r, k] = float(fields[j])
        if m is not None:
            if not _MATERIAL.fullmatch(fields[m].strip()):
                raise RecordingError(f"{csv_path}:{r + 2}: column {m + 1} (material): {excerpt(fields[m])} is not a "
                                     "material name (letters, digits, _.+-)")
            materials.append(fields[m].strip())
    if not np.all(np.isfinite(values)):  # a finite-looking field can overflow: 1e999
        r, k = (int(x) for x in np.argwhere(~np.isfinite(values))[0])
        raise RecordingError(f"{csv_path}:{r + 2}: column {numeric[k] + 1} ({names[numeric[k]]}): "
                             f"{excerpt(lines[r + 1].split(',')[numeric[k]])} is not a finite number")
    big = np.abs(values[:, :n]) > MAX_FLUX_DENSITY_T  # B in mT, or the H samples under the B columns
    if big.any():
        r, k = (int(x) for x in np.argwhere(big)[0])
        raise RecordingError(f"{csv_path}:{r + 2}: column {numeric[k] + 1} ({names[numeric[k]]}): "
                             f"{float(values[r, k])!r} T; |B| must be <= {MAX_FLUX_DENSITY_T:g} T (no iron saturates above "
                             "2.5 T: mT, or H under the B columns?)")
    cols = {names[j]: values[:, k] for k, j in enumerate(numeric)}
    _check_waveform_scalars(csv_path, names, cols)
    scalar_fields = {field: cols[c].copy() if c in cols else None
                     for c, (field, _) in WAVEFORM_COLUMNS.items() if c != "material"}
    return WaveformTable(csv_path, values[:, :n].copy(), values[:, n:2 * n].copy() if has_h else None,
                         material=tuple(materials) if materials else (meta["material"],) * (len(lines) - 1),
                         metadata=meta, **scalar_fields)


def _read_waveform_sidecar(path: Path) -> dict:
    meta = _sidecar_with(path, "waveform table", REQUIRED_WAVEFORM_KEYS)
    if meta["kind"] != "waveform":
        raise RecordingError(f"{path}: key 'kind' must be 'waveform' for a waveform table, got {meta['kind']!r}")
    return meta


def _waveform_header(path: Path, names: list[str]) -> tuple[int, bool, list[str]]:
    """Samples per row, whether H(t) is there, and the scalar columns, from the header."""
    n = 0
    while n < len(names) and names[n] == f"B_t_{n}":
        n += 1
    if n < 2:
        raise RecordingError(f"{path}:1: column {n + 1}: {excerpt(names[n]) if n < len(names) else 'missing'}; a "
                             "waveform table starts with B_t_0, B_t_1, ... (two samples of B(t) at least)")
    has_h = n < len(names) and names[n].startswith("H_t_")
    if has_h:
        for k in range(n):
            got = names[n + k] if n + k < len(names) else None
            if got != f"H_t_{k}":
                raise RecordingError(f"{path}:1: column {n + k + 1}: expected 'H_t_{k}', got "
                                     f"{excerpt(got) if got is not None else 'the end of the header'} (H(t) has as "
                                     f"many samples as B(t): H_t_0..H_t_{n - 1})")
    scalars = names[2 * n if has_h else n:]
    for j, name in enumerate(scalars, start=(2 * n if has_h else n) + 1):
        if name not in WAVEFORM_COLUMNS:
            where = ("a sample out of place (B_t_0.., then H_t_0.., each numbered from 0 without a gap)"
                     if re.fullmatch(r"[BH]_t_\d+", name) else f"not a waveform column ({', '.join(WAVEFORM_COLUMNS)})")
            raise RecordingError(f"{path}:1: column {j}: {excerpt(name)} is {where}")
        if name in names[:j - 1]:
            raise RecordingError(f"{path}:1: column {j}: {name!r} appears twice")
    return n, has_h, scalars


def _check_waveform_scalars(path: Path, names: list[str], cols: dict[str, np.ndarray]) -> None:
    """Frequency > 0, loss >= 0, temperature above absolute zero."""
    rules = {"freq": (lambda c: c > 0, "must be > 0"),
             "ploss": (lambda c: c >= 0, "must be >= 0 (a negative loss would be a core giving energy)"),
             "temp": (lambda c: c > -273.15, "must be above absolute zero (-273.15 degC)")}
    for name, (good, why) in rules.items():
        if name in cols and not np.all(good(cols[name])):
            r = int(np.argmax(~good(cols[name])))
            raise RecordingError(f"{path}:{r + 2}: column {names.index(name) + 1} ({name}): "
                                 f"{float(cols[name][r])!r} {why}")
