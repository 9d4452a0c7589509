"""The material-table reader: the vendored real data read back unchanged, and every defect named
with its file, line and column."""

from __future__ import annotations

import hashlib
import json
import shutil
from collections import Counter
from pathlib import Path

import numpy as np
import pytest
from scipy.constants import mu_0

from hystbench.errors import BenchError, RecordingError
from hystbench.formats.flux_shapes import SINE_DUTY, shape_corners, shape_flux_density
from hystbench.formats.material_data import (REQUIRED_SIDECAR_KEYS, REQUIRED_WAVEFORM_KEYS, read_material_table,
                                             read_waveform_table)

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
    ("50000.0,1e999,180.18", ":5: column 2 (flux_density_peak_T): '1e999' is not a finite number"),  # float(): inf
    ("50000.0,20.0,180.18", ":5: column 2 (flux_density_peak_T): 20.0 must be > 0 and <= 5 T"),  # mT in a T column
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


def _set_sidecar_key(table: Path, key: str, value) -> None:
    side = table.with_suffix(".json")
    side.write_text(json.dumps({**json.loads(side.read_text()), key: value}))


@pytest.mark.parametrize("kind", [["core_loss"], {"a": 1}, None])
def test_a_kind_that_is_no_name_is_refused_naming_the_key(table: Path, kind):
    _set_sidecar_key(table, "kind", kind)
    with pytest.raises(RecordingError, match=r"t\.json: key 'kind' must be one of core_loss, complex_permeability"):
        read_material_table(table)


@pytest.mark.parametrize("temperature", ["hot", None, [25, 50], True, -300.0, 10**400])  # 10^400: OverflowError
def test_a_temperature_that_is_no_temperature_is_refused_naming_the_key(table: Path, temperature):
    _set_sidecar_key(table, "temperature_C", temperature)
    with pytest.raises(RecordingError, match=r"t\.json: key 'temperature_C' must be the measurement's temperature"):
        read_material_table(table)


def test_a_material_name_with_spaces_around_it_is_refused(table: Path):
    """'N87 ' kept a shapes table apart from the N87 sine table: each was diagnosed alone, silently."""
    _set_sidecar_key(table, "material", "N87 ")
    with pytest.raises(RecordingError, match=r"t\.json: key 'material' 'N87 ' has spaces around it"):
        read_material_table(table)


@pytest.mark.parametrize("sidecar", ["T.json", "T.JSON"])
def test_an_upper_case_suffix_is_the_table_as_given(tmp_path: Path, sidecar: str):
    """``N87.CSV`` was read as ``N87.csv`` (no such file), its ``N87.JSON`` called missing."""
    shutil.copy(REAL / "magnet_N87_sine.csv", tmp_path / "T.CSV")
    shutil.copy(REAL / "magnet_N87_sine.json", tmp_path / sidecar)
    t = read_material_table(tmp_path / "T.CSV")
    assert len(t) == len(read_material_table(REAL / "magnet_N87_sine.csv")) and t.path == tmp_path / "T.CSV"


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


def test_a_unit_other_than_the_headers_is_refused(table: Path):
    """The header says Hz; a sidecar saying kHz is a table in other units, not read as Hz."""
    side = table.with_suffix(".json")
    meta = json.loads(side.read_text())
    meta["units"]["frequency_Hz"] = "kHz"
    side.write_text(json.dumps(meta))
    with pytest.raises(RecordingError, match=r"t\.json: key 'units': frequency_Hz is in 'kHz'; this reader takes 'Hz'"):
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
    ("50000.0,0.087,0.0,0.5,0.0,0.5,30000.0", ":7: column 3 (duty_1): 0.0; the rise (duty_1) and the fall (duty_3)"),
    ("50000.0,0.087,1.0,0.0,0.0,0.0,30000.0", ":7: column 5 (duty_3): 0.0; the rise (duty_1) and the fall (duty_3)"),
    ("50000.0,0.087,0.3,0.1,0.4,0.2,30000.0", ":7: columns 4 and 6 (duty_2, duty_4): 0.1 and 0.2; MagNet's"),
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


# --- measured waveforms (mag-net-hub) ---------------------------------------------------------

HUB = REAL / "mag-net-hub"


def test_waveform_files_read_with_their_sources():
    p = read_waveform_table(HUB / "maghub_ploss_at_450kWpm3.csv")
    assert len(p) == 90 and p.samples == 1024 and p.b_t.shape == (90, 1024) and p.h_t is None
    assert p.metadata["units"] == {"B_t_*": "T", "freq": "Hz", "temp": "degC", "ploss": "W/m^3"}
    assert dict(Counter(p.material)) == p.metadata["materials"]
    assert set(p.temperature_c.tolist()) == {25.0, 50.0, 70.0, 90.0}
    assert np.all((p.loss_w_per_m3 > 450e3) & (p.loss_w_per_m3 < 451e3))  # the file name's 450 kW/m^3
    assert np.all((p.frequency_hz >= 50e3) & (p.frequency_hz <= 500e3)) and np.abs(p.b_t).max() < 0.32
    first = (HUB / "maghub_ploss_at_450kWpm3.csv").read_text().splitlines()[1].split(",")  # parsed independently
    assert p.b_t[0].tolist() == [float(x) for x in first[:1024]] and p.material[0] == first[-1]
    assert [p.frequency_hz[0], p.temperature_c[0], p.loss_w_per_m3[0]] == [float(x) for x in first[1024:1027]]

    s = read_waveform_table(HUB / "maghub_3C90_sequence.csv")
    assert len(s) == 6 and s.samples == 1024 and s.h_t is not None and s.h_t.shape == (6, 1024)
    assert s.frequency_hz is None and s.loss_w_per_m3 is None and s.material == ("3C90",) * 6
    assert s.temperature_c.tolist() == [50.0, 25.0, 25.0, 25.0, 25.0, 25.0]
    assert s.metadata["units"] == {"B_t_*": "T", "H_t_*": "A/m", "temp": "degC"}
    # B against H: a slope of a ferrite's relative permeability, so T and A/m (not mT, not kA/m)
    mu_r = [np.polyfit(h, b, 1)[0] / mu_0 for b, h in zip(s.b_t, s.h_t)]
    assert all(2000 < m < 6000 for m in mu_r)
    for t in (p, s):  # the vendored bytes are the ones the sidecar's source names
        assert hashlib.sha256(t.path.read_bytes()).hexdigest() == t.metadata["source"]["sha256"]
        assert t.metadata["licence"]["name"] == "MIT" and (HUB / t.metadata["licence"]["file"]).is_file()


def test_measured_sequences_absorb_energy():
    """The check the data allow instead of f * closed-integral(H dB) against a loss column: no
    vendored file has both H(t) and a measured loss (the 450 kW/m^3 rows have no H; the sequence
    rows have no frequency, no loss, and are not periodic, so there is no cycle to close).

    Over a sequence, integral(H dB) is the energy per volume the core took: its loss plus the
    change of what it stores, about d(HB)/2 for a core this close to linear (mu_r 3400-3900).
    A passive lossy core takes energy.  Measured: 0.27 to 16.2 J/m^3 per sequence, at least 3.6
    times |d(HB)/2| (<= 0.52 J/m^3); asserted: more than twice.  (Over the 64 us the sequences last
    at the 16 MHz the repository's README gives, that is 4 to 250 kW/m^3 on average: the order of
    the MagNet tables' losses at those flux densities.)"""
    s = read_waveform_table(HUB / "maghub_3C90_sequence.csv")
    assert s.h_t is not None
    for b, h in zip(s.b_t, s.h_t):
        taken = float(np.sum((h[1:] + h[:-1]) / 2 * np.diff(b)))  # trapezoidal integral(H dB)
        stored = abs(h[-1] * b[-1] - h[0] * b[0]) / 2
        assert taken > 2 * stored and taken > 0


def _duty_grid() -> list[tuple[float, ...]]:
    meta = json.loads((REAL / "magnet_N87_shapes.json").read_text())
    return [tuple(float(x) for x in k.split(",")) for k in meta["duty_tuples"]]


def _fit(b: np.ndarray, model: np.ndarray) -> float:
    """rms(model shifted to match - b) / amplitude, the best of all circular shifts (the measured
    period starts anywhere)."""
    shift = int(np.argmax(np.fft.ifft(np.fft.fft(b) * np.conj(np.fft.fft(model))).real))
    return float(np.sqrt(np.mean((np.roll(model, shift) - b) ** 2)) / ((b.max() - b.min()) / 2))


def _shape_of(b: np.ndarray) -> tuple[tuple[float, ...], float, float]:
    """The MagNet waveform (a duty tuple, or SINE_DUTY) closest to one measured period of B(t),
    its rms misfit / amplitude, and the misfit of the same tuple with truly flat intervals."""
    b = b - (b.max() + b.min()) / 2
    bpk, phase = (b.max() - b.min()) / 2, np.arange(b.size) / b.size
    fits = [(d, _fit(b, shape_flux_density(d, bpk, phase))) for d in [*_duty_grid(), SINE_DUTY]]
    duty, err = min(fits, key=lambda x: x[1])
    if duty == SINE_DUTY:
        return duty, err, err
    d1, d2, d3, _ = duty
    flat = np.interp(phase, [0, d1, d1 + d2, d1 + d2 + d3, 1], [-bpk, bpk, bpk, -bpk, -bpk])
    return duty, err, _fit(b, flat)


@pytest.fixture(scope="module")
def hub_shapes() -> list[tuple[tuple[float, ...], float, float]]:
    return [_shape_of(b) for b in read_waveform_table(HUB / "maghub_ploss_at_450kWpm3.csv").b_t]


def test_measured_waveforms_are_magnets_shapes(hub_shapes):
    """The 90 measured periods of B(t) of the 450 kW/m^3 file (another source than the MagNet
    wheel: mag-net-hub's test file) against flux_shapes: each is a sine or one of the 25 duty
    tuples, rebuilt within 3 % rms of its amplitude (measured: 84 shapes, median 0.87 %, worst
    2.9 %; 6 sines, worst 1.4 %).  The series capacitor's slope between the ramps is real: in the
    37 rows with d1 != d3 and intervals between the ramps, drawing those intervals flat fits 3.4x
    worse at the least (1.0 % -> 3.5 % for (0.5, 0.1, 0.3, 0.1)), up to 1.1 % -> 24 % for
    (0.1, 0.3, 0.3, 0.3); asserted: 2.5x."""
    errors = [err for _, err, _ in hub_shapes]
    sines = [d for d, _, _ in hub_shapes if d == SINE_DUTY]
    assert max(errors) < 0.03 and len(sines) == 6 and np.median(errors) < 0.012
    sloped = [(err, flat) for (d1, d2, d3, _), err, flat in (x for x in hub_shapes if x[0] != SINE_DUTY)
              if d2 > 0 and abs(d1 - d3) > 0.05]
    assert len(sloped) > 30 and all(flat > 2.5 * err for err, flat in sloped)


def test_measured_loss_agrees_with_magnet_tables(hub_shapes):
    """The 450 kW/m^3 file's measured loss against the MagNet wheel's tables of the same material
    at the same temperature (25 degC) and the same waveform (the duty tuple or sine found above):
    the table's rows of that waveform nearest in (log f, log B), 12 of them, give a plane of
    log P in log f, log B; the ratio is file / plane at the row's f and amplitude.  Two
    measurement campaigns (the wheel's of 2021, the challenge's), other cores of the same
    material, an interpolation: measured ratios 0.95 to 1.14 (3C90 sine 0.95, 3C90 (0.9, 0,
    0.1, 0) 1.05, 3E6 (0.3, 0.3, 0.1, 0.3) 0.95, N87 four shapes 1.09-1.14); asserted within
    -15 % / +20 %.  It checks the units and meanings both sources claim: Hz, T of amplitude,
    W/m^3, the duties' order."""
    p = read_waveform_table(HUB / "maghub_ploss_at_450kWpm3.csv")
    ratios = []
    for r, (duty, _, _) in enumerate(hub_shapes):
        if p.material[r] not in SHAPES_ROWS or p.temperature_c[r] != 25:
            continue
        kind = "sine" if duty == SINE_DUTY else "shapes"
        t = read_material_table(REAL / f"magnet_{p.material[r]}_{kind}.csv")
        same = np.all(t.duty == np.array(duty), axis=1)
        lf, lb = np.log10(t.frequency_hz[same]), np.log10(t.flux_density_t[same])
        lp = np.log10(t.columns["loss_W_per_m3"][same])
        f, bpk = p.frequency_hz[r], (p.b_t[r].max() - p.b_t[r].min()) / 2
        near = np.argsort(np.hypot(lf - np.log10(f), lb - np.log10(bpk)))[:12]
        a = np.column_stack([np.ones(12), lf[near] - np.log10(f), lb[near] - np.log10(bpk)])
        ratios.append(p.loss_w_per_m3[r] / 10 ** np.linalg.lstsq(a, lp[near], rcond=None)[0][0])
    assert len(ratios) == 7 and all(0.85 < x < 1.2 for x in ratios), ratios


def _waveform(folder: Path, header: str, rows: list[str], meta: dict | None = None, name: str = "w") -> Path:
    meta = {"kind": "waveform", "row": "a test", "source": {"made": "here"}, "licence": {"name": "MIT"},
            "units": {"B_t_*": "T", "H_t_*": "A/m", "freq": "Hz", "temp": "degC", "ploss": "W/m^3"}, **(meta or {})}
    (folder / f"{name}.csv").write_text("\n".join([header, *rows]) + "\n")
    (folder / f"{name}.json").write_text(json.dumps(meta))
    return folder / f"{name}.csv"


GOOD_HEADER = "B_t_0,B_t_1,B_t_2,H_t_0,H_t_1,H_t_2,freq,temp,ploss,material"
GOOD_ROW = "0.1,0.0,-0.1,5,0,-5,100000.0,25,1000.5,N87"


def test_a_small_waveform_table_reads(tmp_path: Path):
    t = read_waveform_table(_waveform(tmp_path, GOOD_HEADER, [GOOD_ROW, GOOD_ROW.replace("N87", "3C90")]))
    assert t.samples == 3 and len(t) == 2 and t.b_t[0].tolist() == [0.1, 0.0, -0.1] and t.h_t[1].tolist() == [5, 0, -5]
    assert t.material == ("N87", "3C90") and t.loss_w_per_m3.tolist() == [1000.5, 1000.5]


@pytest.mark.parametrize("header, message", [
    ("B_t_0,B_t_2,freq", ":1: column 2: 'B_t_2'; a waveform table starts with B_t_0, B_t_1"),
    ("x,B_t_0,B_t_1", ":1: column 1: 'x'; a waveform table starts with B_t_0"),
    ("B_t_0,B_t_1,B_t_2,H_t_0,H_t_1,freq,temp,ploss,material", ":1: column 6: expected 'H_t_2', got 'freq'"),
    ("B_t_0,B_t_1,B_t_2,H_t_0,H_t_1", ":1: column 6: expected 'H_t_2', got the end of the header"),
    ("B_t_0,B_t_1,B_t_2,H_t_0,H_t_1,H_t_2,freq,temp,ploss,Material", ":1: column 10: 'Material' is not a waveform "
                                                                     "column (freq, temp, ploss, material)"),
    ("B_t_0,B_t_1,B_t_2,H_t_0,H_t_1,H_t_2,freq,temp,ploss,B_t_3", ":1: column 10: 'B_t_3' is a sample out of place"),
    ("B_t_0,B_t_1,B_t_2,H_t_0,H_t_1,H_t_2,freq,temp,freq,material", ":1: column 9: 'freq' appears twice"),
])
def test_bad_waveform_header_is_named(tmp_path: Path, header: str, message: str):
    path = _waveform(tmp_path, header, [GOOD_ROW])
    with pytest.raises(RecordingError) as err:
        read_waveform_table(path)
    assert str(err.value).startswith(f"{path}{message}"), str(err.value)


@pytest.mark.parametrize("row, message", [
    ("nan,0.0,-0.1,5,0,-5,100000.0,25,1000.5,N87", ":3: column 1 (B_t_0): 'nan' is not a finite number"),
    ("0.1,0.0,-0.1,5,inf,-5,100000.0,25,1000.5,N87", ":3: column 5 (H_t_1): 'inf' is not a finite number"),
    ("0.1,0.0,-0.1,5,0,-5,1e999,25,1000.5,N87", ":3: column 7 (freq): '1e999' is not a finite number"),
    ("0.1,0.0,-0.1,5,0,-5,100000.0,,1000.5,N87", ":3: column 8 (temp): empty field"),
    ("0.1,0.0,-0.1,5,0,-5,100000.0,25,1000.5", ":3: 9 fields, the header has 10"),
    ("0.1,0.0,-0.1,5,0,-5,100000.0,25,1000.5,N87,1", ":3: 11 fields, the header has 10"),
    ("0.1,0.0,-0.1,5,0,-5,100000.0,25,-3.0,N87", ":3: column 9 (ploss): -3.0 must be >= 0"),
    ("0.1,0.0,-0.1,5,0,-5,0,25,1000.5,N87", ":3: column 7 (freq): 0.0 must be > 0"),
    ("0.1,0.0,-0.1,5,0,-5,100000.0,-300,1000.5,N87", ":3: column 8 (temp): -300.0 must be above absolute zero"),
    ("0.1,0.0,-0.1,5,0,-5,100000.0,25,1000.5,N 87", ":3: column 10 (material): 'N 87' is not a material name"),
    ("0.1,0.0,-0.1,5,0,-5,100000.0,25,1000.5,", ":3: column 10 (material): '' is not a material name"),
    # B in mT under a sidecar that says T (or the H samples under the B columns): 1000 times off, refused
    ("100.0,0.0,-100.0,5,0,-5,100000.0,25,1000.5,N87", ":3: column 1 (B_t_0): 100.0 T; |B| must be <= 5 T"),
    ("0.1,0.0,-5.5,5,0,-5,100000.0,25,1000.5,N87", ":3: column 3 (B_t_2): -5.5 T; |B| must be <= 5 T"),
])
def test_bad_waveform_value_named_by_line_and_column(tmp_path: Path, row: str, message: str):
    path = _waveform(tmp_path, GOOD_HEADER, [GOOD_ROW, row])
    with pytest.raises(RecordingError) as err:
        read_waveform_table(path)
    assert str(err.value).startswith(f"{path}{message}"), str(err.value)


@pytest.mark.parametrize("key", REQUIRED_WAVEFORM_KEYS)
def test_missing_waveform_sidecar_key_is_named(tmp_path: Path, key: str):
    path = _waveform(tmp_path, GOOD_HEADER, [GOOD_ROW])
    meta = json.loads(path.with_suffix(".json").read_text())
    del meta[key]
    path.with_suffix(".json").write_text(json.dumps(meta))
    with pytest.raises(RecordingError, match=rf"w\.json: missing key '{key}'"):
        read_waveform_table(path)


@pytest.mark.parametrize("meta, header, message", [
    ({"kind": "core_loss"}, GOOD_HEADER, "key 'kind' must be 'waveform'"),
    ({"units": {"B_t_*": "T", "H_t_*": "A/m", "freq": "kHz", "temp": "degC", "ploss": "W/m^3"}}, GOOD_HEADER,
     "key 'units': freq is in 'kHz'; this reader takes 'Hz'"),
    ({"units": {"B_t_*": "mT", "H_t_*": "A/m", "freq": "Hz", "temp": "degC", "ploss": "W/m^3"}}, GOOD_HEADER,
     "key 'units': B_t_\\* is in 'mT'"),
    ({"units": {"B_t_*": "T", "freq": "Hz", "temp": "degC", "ploss": "W/m^3"}}, GOOD_HEADER,
     "key 'units' must give the unit of every column \\(B_t_\\*, H_t_\\*, freq, temp, ploss\\)"),
    ({}, GOOD_HEADER.replace(",material", ""), "missing key 'material' \\(a non-empty string: the file has no"),
])
def test_waveform_sidecar_must_match_the_file(tmp_path: Path, meta: dict, header: str, message: str):
    row = GOOD_ROW if header.endswith("material") else GOOD_ROW.rsplit(",", 1)[0]
    path = _waveform(tmp_path, header, [row], meta)
    with pytest.raises(RecordingError, match=rf"^{path.with_suffix('.json')}: {message}"):
        read_waveform_table(path)


def test_waveform_without_material_column_takes_the_sidecars(tmp_path: Path):
    path = _waveform(tmp_path, GOOD_HEADER.replace(",material", ""), [GOOD_ROW.rsplit(",", 1)[0]] * 3,
                     {"material": "3C90"})
    assert read_waveform_table(path).material == ("3C90",) * 3


def test_waveform_missing_sidecar_and_no_rows(tmp_path: Path):
    path = _waveform(tmp_path, GOOD_HEADER, [])
    (tmp_path / "w.csv").write_text(GOOD_HEADER + "\n")
    with pytest.raises(RecordingError, match=r"w\.csv: no rows after the header"):
        read_waveform_table(path)
    path.with_suffix(".json").unlink()
    with pytest.raises(RecordingError, match=r"w\.json: missing sidecar"):
        read_waveform_table(path)
