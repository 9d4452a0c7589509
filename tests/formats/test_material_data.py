"""The material-table reader: the vendored real data read back unchanged, and every defect named
with its file, line and column."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from hystbench.errors import BenchError, RecordingError
from hystbench.formats.flux_shapes import shape_corners, shape_flux_density
from hystbench.formats.material_data import REQUIRED_SIDECAR_KEYS, read_material_table

REAL = Path(__file__).resolve().parents[1] / "data" / "real"


def test_vendored_tables_read_with_their_sources():
    n87 = read_material_table(REAL / "magnet_N87_sine.csv")
    assert n87.kind == "core_loss" and n87.material == "N87" and len(n87) == 964
    assert n87.metadata["licence"]["name"] == "MIT" and (REAL / n87.metadata["licence"]["file"]).is_file()
    # first data line of the file, parsed here independently of the reader
    first = (REAL / "magnet_N87_sine.csv").read_text().splitlines()[1].split(",")
    assert [n87.frequency_hz[0], n87.flux_density_t[0], n87.columns["loss_W_per_m3"][0]] == [float(x) for x in first]
    mu = read_material_table(REAL / "N87_mu_large.csv")
    assert mu.kind == "complex_permeability" and len(mu) == 4572
    assert np.all(mu.columns["mu_imag"] < 0) and (REAL / mu.metadata["licence"]["file"]).is_file()
    for name in ("magnet_3C90_sine", "magnet_3E6_sine", "magnet_N49_sine"):
        t = read_material_table(REAL / f"{name}.csv")
        assert t.metadata["temperature_C"] == 25.0 and np.all(t.columns["loss_W_per_m3"] > 0)


@pytest.fixture
def table(tmp_path: Path) -> Path:
    for suffix in (".csv", ".json"):
        shutil.copy(REAL / f"magnet_N87_sine{suffix}", tmp_path / f"t{suffix}")
    return tmp_path / "t.csv"


def _edit_line(path: Path, lineno: int, text: str) -> None:
    lines = path.read_text().splitlines()
    lines[lineno - 1] = text
    path.write_text("\n".join(lines) + "\n")


@pytest.mark.parametrize("line, message", [
    ("50000.0,nan,180.18", ":5: column 2 (flux_density_peak_T): 'nan' is not a finite number"),
    ("50000.0,0.01,inf", ":5: column 3 (loss_W_per_m3): 'inf' is not a finite number"),
    ("50000.0,0.01,-3.5", ":5: column 3 (loss_W_per_m3): -3.5 must be >= 0"),
    ("50000.0,0.01,", ":5: column 3 (loss_W_per_m3): empty field"),
    ("50000.0,0.01", ":5: 2 fields, the header has 3"),
    ("0,0.01,5", ":5: column 1 (frequency_Hz): 0.0 must be > 0"),
    ("50000.0,0.01,1_0", ":5: column 3 (loss_W_per_m3): '1_0' is not a finite number"),
])
def test_bad_value_named_by_line_and_column(table: Path, line: str, message: str):
    _edit_line(table, 5, line)
    with pytest.raises(RecordingError) as err:
        read_material_table(table)
    assert str(err.value) == f"{table}{message}" or str(err.value).startswith(f"{table}{message}")


def test_wrong_header_is_named(table: Path):
    _edit_line(table, 1, "frequency_Hz,flux_density_T,loss_W_per_m3")
    with pytest.raises(RecordingError, match=r"t\.csv:1: header .* is not the core_loss layout"):
        read_material_table(table)


@pytest.mark.parametrize("key", REQUIRED_SIDECAR_KEYS)
def test_missing_sidecar_key_is_named(table: Path, key: str):
    side = table.with_suffix(".json")
    meta = json.loads(side.read_text())
    del meta[key]
    side.write_text(json.dumps(meta))
    with pytest.raises(BenchError, match=rf"t\.json: missing key '{key}'"):
        read_material_table(table)


def test_missing_sidecar_and_bad_json(table: Path):
    side = table.with_suffix(".json")
    side.write_text('{"material": "N87",\n "kind": }')
    with pytest.raises(RecordingError, match=r"t\.json:2: column \d+: not valid JSON"):
        read_material_table(table)
    side.unlink()
    with pytest.raises(RecordingError, match=r"t\.json: missing sidecar"):
        read_material_table(table)


def test_units_must_cover_the_columns(table: Path):
    side = table.with_suffix(".json")
    meta = json.loads(side.read_text())
    meta["units"].pop("loss_W_per_m3")
    side.write_text(json.dumps(meta))
    with pytest.raises(RecordingError, match=r"key 'units' must give the unit of every column"):
        read_material_table(table)


def test_permeability_sign_is_checked(tmp_path: Path):
    for suffix in (".csv", ".json"):
        shutil.copy(REAL / f"N87_mu_large{suffix}", tmp_path / f"m{suffix}")
    _edit_line(tmp_path / "m.csv", 3, "50000.0,0.07,3400.0,12.5")
    with pytest.raises(RecordingError, match=r"m\.csv:3: column 4 \(mu_imag\): 12.5 must be <= 0"):
        read_material_table(tmp_path / "m.csv")


# --- MagNet's triangular/trapezoidal rows: the duty columns ----------------------------------

SHAPES_ROWS = {"N87": 24773, "3C90": 24088, "3E6": 17855, "N49": 17692}


@pytest.mark.parametrize("mat", SHAPES_ROWS)
def test_shapes_tables_read_with_their_duties(mat: str):
    t = read_material_table(REAL / f"magnet_{mat}_shapes.csv")
    assert t.kind == "core_loss" and t.material == mat and len(t) == SHAPES_ROWS[mat]
    assert t.metadata["excitation"] == "triangular_trapezoidal" and (REAL / t.metadata["licence"]["file"]).is_file()
    assert t.metadata["units"] == {"frequency_Hz": "Hz", "flux_density_peak_T": "T", "duty_1": "1", "duty_2": "1",
                                   "duty_3": "1", "duty_4": "1", "loss_W_per_m3": "W/m^3"}
    first = (REAL / f"magnet_{mat}_shapes.csv").read_text().splitlines()[1].split(",")
    parsed = [t.frequency_hz[0], t.flux_density_t[0], *t.duty[0], t.columns["loss_W_per_m3"][0]]
    assert parsed == [float(x) for x in first]
    duty = t.duty
    assert duty.shape == (len(t), 4) and not np.any(duty[:, 0] == -1)  # no sine row here
    assert np.all(np.abs(duty.sum(axis=1) - 1) < 1e-12) and np.all(duty[:, 1] == duty[:, 3])
    tuples, counts = np.unique(duty, axis=0, return_counts=True)
    listed = {tuple(float(x) for x in k.split(",")): n for k, n in t.metadata["duty_tuples"].items()}
    assert {tuple(d): int(c) for d, c in zip(tuples.tolist(), counts)} == listed and len(listed) == 25
    # the same store's sine rows are the other table: together, the whole store
    whole = len(t) + len(read_material_table(REAL / f"magnet_{mat}_sine.csv"))
    assert f"the {len(t)} of {whole} rows" in t.metadata["trimmed"]


def test_a_table_without_duties_is_all_sine_and_unchanged():
    t = read_material_table(REAL / "magnet_N87_sine.csv")
    assert list(t.columns) == ["frequency_Hz", "flux_density_peak_T", "loss_W_per_m3"]
    assert t.duty.shape == (964, 4) and np.all(t.duty == -1)


@pytest.fixture
def shapes(tmp_path: Path) -> Path:
    lines = (REAL / "magnet_3E6_shapes.csv").read_text().splitlines()[:40]
    (tmp_path / "s.csv").write_text("\n".join(lines) + "\n")
    shutil.copy(REAL / "magnet_3E6_shapes.json", tmp_path / "s.json")
    return tmp_path / "s.csv"


@pytest.mark.parametrize("line, message", [
    ("50000.0,0.087,1.5,0.0,-0.5,0.0,30000.0", ":7: column 3 (duty_1): 1.5 must be a fraction in [0, 1]"),
    ("50000.0,0.087,0.1,0.1,0.9,0.1,30000.0", ":7: columns 3-6 (duty_1..duty_4): [0.1, 0.1, 0.9, 0.1] sum to"),
    ("50000.0,0.087,0.1,0.0,nan,0.0,30000.0", ":7: column 5 (duty_3): 'nan' is not a finite number"),
    ("50000.0,0.087,-1,-1,-1,0.0,30000.0", ":7: column 3 (duty_1): -1.0 must be a fraction in [0, 1] (or all four -1"),
    ("50000.0,0.087,0.1,0.0,0.9,0.0", ":7: 6 fields, the header has 7"),
])
def test_bad_duty_named_by_line_and_column(shapes: Path, line: str, message: str):
    _edit_line(shapes, 7, line)
    with pytest.raises(RecordingError) as err:
        read_material_table(shapes)
    assert str(err.value).startswith(f"{shapes}{message}")


def test_a_sine_row_in_a_shapes_table_is_all_minus_one(shapes: Path):
    _edit_line(shapes, 7, "50000.0,0.087,-1,-1,-1,-1,30000.0")
    t = read_material_table(shapes)
    assert t.duty[5].tolist() == [-1, -1, -1, -1] and (t.duty[:, 0] == -1).sum() == 1


def test_duty_columns_out_of_place_are_not_the_layout(shapes: Path):
    _edit_line(shapes, 1, "frequency_Hz,flux_density_peak_T,loss_W_per_m3,duty_1,duty_2,duty_3,duty_4")
    with pytest.raises(RecordingError, match=r"s\.csv:1: header .* is not the core_loss layout "
                                             r"'frequency_Hz,flux_density_peak_T,loss_W_per_m3' or "):
        read_material_table(shapes)


# --- B(t) of a MagNet row ---------------------------------------------------------------------

def test_symmetric_triangle_is_a_triangle_of_the_peak():
    """Duty (0.5, 0, 0.5, 0): B rises from -Bpk to +Bpk over T/2 and falls back; on the rising
    segment dB/dt = 2 Bpk / (d1 T), computed here from the sampled waveform."""
    bpk, f, n = 0.1, 100e3, 4000
    phase = np.arange(n) / n
    b = shape_flux_density((0.5, 0.0, 0.5, 0.0), bpk, phase)
    assert b[0] == pytest.approx(-bpk) and b[n // 2] == pytest.approx(bpk)
    assert b[n // 4] == pytest.approx(0, abs=1e-15) and b[3 * n // 4] == pytest.approx(0, abs=1e-15)
    assert np.allclose(b, bpk * (1 - 4 * np.abs(phase - 0.5)))  # the triangle written independently
    dbdt = np.diff(b) * f * n  # dB / (T / n)
    assert np.allclose(dbdt[: n // 2 - 1], 2 * bpk / (0.5 / f)) and np.allclose(dbdt[n // 2 + 1:], -2 * bpk / (0.5 / f))


@pytest.mark.parametrize("d1", [0.1, 0.2, 0.7, 0.9])
def test_asymmetric_triangle_slopes(d1: float):
    bpk, n = 0.2, 10000
    b = shape_flux_density((d1, 0.0, 1 - d1, 0.0), bpk, np.arange(n) / n)
    rise, fall = np.diff(b)[: int(d1 * n) - 2] * n, np.diff(b)[int(d1 * n) + 2:] * n
    assert np.allclose(rise, 2 * bpk / d1) and np.allclose(fall, -2 * bpk / (1 - d1))
    assert b.max() == pytest.approx(bpk, rel=1e-3) and b.min() == pytest.approx(-bpk)


def _magnet_corners(dp: float, dn: float, d0: float, flux: float) -> tuple[list[float], list[float]]:
    """mag-net 0.1.0, magnet/core.py core_loss_iGSE_trapezoidal, transcribed (duty = [d_P, d_N, d_0])."""
    frac_time = [0, dp, dp + d0, 1 - d0, 1]
    if dp > dn:
        bp = flux
        bn = -bp * ((-1 - dp + dn) * dn) / ((1 - dp + dn) * dp)
    else:
        bn = flux
        bp = -bn * ((1 - dp + dn) * dp) / ((-1 - dp + dn) * dn)
    return frac_time, [-bp, bp, bn, -bn, -bp]


@pytest.mark.parametrize("mat", ["N87"])
def test_every_magnet_duty_tuple_gives_magnets_own_corners(mat: str):
    """The helper derives B from the bridge voltages through the series capacitor; MagNet writes
    the corner values as a formula. Both, for the 25 duty tuples of the table, and the peak is
    the amplitude (max B = -min B = Bpk) with a zero mean."""
    meta = json.loads((REAL / f"magnet_{mat}_shapes.json").read_text())
    for key in meta["duty_tuples"]:
        d1, d2, d3, d4 = (float(x) for x in key.split(","))
        t, b = shape_corners((d1, d2, d3, d4), 0.25)
        ft, fb = _magnet_corners(d1, d3, d2, 0.25)
        assert np.allclose(t, ft, atol=1e-15) and np.allclose(b, fb, atol=1e-15), key
        w = shape_flux_density((d1, d2, d3, d4), 0.25, np.arange(100000) / 100000)
        assert w.max() == pytest.approx(0.25) and w.min() == pytest.approx(-0.25) and abs(w.mean()) < 1e-5


def test_bad_duty_tuples_are_refused():
    with pytest.raises(ValueError, match="summing to 1"):
        shape_flux_density((0.5, 0.1, 0.5, 0.1), 0.1, 0.0)
    with pytest.raises(ValueError, match="duty_2 == duty_4"):
        shape_flux_density((0.5, 0.2, 0.3, 0.0), 0.1, 0.0)
    with pytest.raises(ValueError, match="4 fractions"):
        shape_flux_density((0.5, 0.5), 0.1, 0.0)
    with pytest.raises(ValueError, match="> 0"):
        shape_flux_density((0.5, 0.0, 0.5, 0.0), -0.1, 0.0)
    with pytest.raises(ValueError, match="duty_1 .rising. and duty_3 .falling. must be > 0"):
        shape_flux_density((0.0, 0.5, 0.0, 0.5), 0.1, 0.0)
    ph = np.array([0.0, 0.25, 1.25])
    assert np.allclose(shape_flux_density((-1, -1, -1, -1), 0.1, ph), [0.0, 0.1, 0.1])  # a sine row
