"""The loss-table diagnosis: names what a synthetic table was built with (and nothing when nothing
rate dependent is in it), and on the vendored MagNet N87 data names the rate-dependent term and
shrinks the held-out error by at least what an independent least-squares fit here finds; with MagNet's
triangles and trapezoids (issue 28) the shape factors match an independent integration, a sine table's
figures are unchanged, a synthetic shapes table gives back its classical term, and the real N87 sine
and shapes tables are diagnosed together, held out per shape."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from hystbench.analysis.diagnosis.loss_separation import diagnose_energy, diagnose_loss_table
from hystbench.errors import EstimationError, RecordingError
from hystbench.formats.material_data import read_material_table

pytestmark = pytest.mark.slow(30)  # ~30 s with the term library: handed to a worker before lighter files (tests/conftest.py)

REAL = Path(__file__).resolve().parents[2] / "data" / "real"
K_H, BETA = 0.5, 2.6  # J/m^3 per cycle at 0.1 T (N87-like), and its B exponent
NOISE_LN = 0.02  # 2 % multiplicative scatter, about MagNet's repeatability (noise floor 0.010 log10)


def synthetic(k_c: float = 0.0, k_e: float = 0.0, seed: int = 1):
    """A MagNet-like grid: 46 frequencies 50-500 kHz x 20 flux densities 10-250 mT, W known exactly."""
    rng = np.random.default_rng(seed)
    f = np.repeat(np.arange(50e3, 501e3, 10e3), 20)
    b = np.tile(np.geomspace(0.01, 0.25, 20), 46) * np.exp(rng.uniform(-0.05, 0.05, f.size))
    w = K_H * (b / 0.1) ** BETA + k_c * f * b**2 + k_e * np.sqrt(f) * b**1.5
    return f, b, w * np.exp(rng.normal(0.0, NOISE_LN, f.size))


def _within(est: dict, truth: float, sigmas: float = 3.0) -> bool:
    return abs(est["value"] - truth) <= sigmas * est["std"]


@pytest.mark.parametrize("seed", [1, 2])
def test_classical_term_named_with_its_value(seed: int):
    k_c = 1e-4  # N87's fitted size: about 40 % of W at 200 kHz, 100 mT
    r = diagnose_energy(*synthetic(k_c=k_c, seed=seed), split="low_third")
    assert r["effect"] == "lamination_eddy_currents" and r["effects"] == ["lamination_eddy_currents"]
    p = r["parameters"]["lamination_eddy_currents"]
    assert _within(p["k_c_J_s_per_m3_T2"], k_c)
    assert p["sigma_d2_S_m"]["value"] == pytest.approx(6 * p["k_c_J_s_per_m3_T2"]["value"] / math.pi**2)
    assert _within(r["recalibrated"]["static_hysteresis.beta"], BETA)
    assert _within(r["recalibrated"]["static_hysteresis.k_h_J_per_m3_at_0.1T"], K_H)
    # the model with the true term predicts the held-out rows to the noise: after ~ 1 noise floor
    assert r["residual_after"] < 1.5 and r["improvement"] > 5
    # located: energy per cycle grows with f beyond the baseline, where the term lives
    assert r["located"]["trend"]["slope_log_f"] > 5 * r["located"]["trend"]["slope_log_f_std"]
    # the measured noise floor is the scatter put in (log10 units)
    assert r["noise_floor"]["log10_W"] == pytest.approx(NOISE_LN / math.log(10), rel=0.15)
    json.dumps(r, allow_nan=False)


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_rate_independent_table_names_nothing(seed: int):
    r = diagnose_energy(*synthetic(seed=seed), split="low_third")
    assert r["effect"] is None and r["effects"] == []
    assert r["residual_before"] < 1.5  # held-out error at the noise floor: nothing to locate
    assert not r["beyond_catalogue"]["needed"]


def test_excess_term_is_found_and_given_its_catalogue_name():
    """Bertotti's excess loss is the catalogue's excess_loss (its field k sqrt|dB/dt| takes, per cycle
    of a sine, k B^1.5 f^0.5 (2 pi)^1.5 <|cos|^1.5> = 8.763 k B^1.5 f^0.5, computed here)."""
    k_e = 0.03  # about half of W at 200 kHz, 100 mT
    r = diagnose_energy(*synthetic(k_e=k_e), split="low_third")
    assert r["effects"][0] == "excess_loss" and r["effect"] == "excess_loss" and r["not_in_catalogue"] == []
    p = r["parameters"]["excess_loss"]
    assert _within(p["k_e_J_per_m3_Hz0.5_T1.5"], k_e)
    phi = (np.arange(100_000) + 0.5) / 100_000
    c = (2 * math.pi) ** 1.5 * np.mean(np.abs(np.cos(2 * math.pi * phi)) ** 1.5)
    assert c == pytest.approx(8.763, abs=1e-3)
    assert _within(p["coefficient_a_per_m_per_sqrt_t_per_s"], k_e / c)


def test_a_datasheet_curve_at_one_flux_density_gives_json_with_its_undetermined_exponents_null():
    """Loss against frequency at 0.1 T alone (a datasheet's curve): the B exponents are not determined
    by the rows, so they have no standard error (null, not NaN that --json cannot write), and the
    classical term is named across the band."""
    rng = np.random.default_rng(4)
    f = np.geomspace(50e3, 500e3, 20)
    b = np.full(f.size, 0.1)
    w = (K_H + 1e-4 * f * b**2) * np.exp(rng.normal(0.0, NOISE_LN, f.size))
    r = diagnose_energy(f, b, w, split="interleaved")
    json.dumps(r, allow_nan=False)
    assert r["recalibrated"]["static_hysteresis.beta"]["std"] is None
    assert r["effects"] == ["lamination_eddy_currents"]
    assert "every row at one flux density (100 mT): the loss's B dependence (beta, each term's delta) is not" \
        in r["verdict"]
    low = diagnose_energy(f, b, w)  # calibrated on the lowest third: 6 rows, nothing decided, and it says why
    assert low["effects"] == [] and "only 6 calibration rows: too few to decide a rate term" in low["verdict"]
    assert "calibration rows" not in diagnose_energy(*synthetic(k_c=1e-4))["verdict"]


def test_a_mistyped_row_is_left_out_and_named_and_the_classical_term_still_found():
    """One loss typed x100 (a hostile probe's table): it had set the noise floor to 8x the scatter and
    the diagnosis said "nothing significant".  Left out and named, the eddy current is found with its
    size, and the noise floor is the scatter put in; a table whose rows are off by the dozen is refused."""
    from hystbench.analysis.diagnosis.loss_separation import MAX_OUTLIER_SHARE

    k_c = 1e-4
    f, b, w = synthetic(k_c=k_c, seed=2)
    w[[13, 400]] *= [100.0, 0.3]
    names = [f"t.csv:{i + 2}" for i in range(f.size)]
    r = diagnose_energy(f, b, w, row_names=names)
    assert r["outlier_rows"] == [13, 400] and "2 rows left out" in r["verdict"] and "t.csv:15, t.csv:402" in r["verdict"]
    assert r["effects"] == ["lamination_eddy_currents"]
    assert _within(r["parameters"]["lamination_eddy_currents"]["k_c_J_s_per_m3_T2"], k_c)
    assert r["noise_floor"]["log10_W"] == pytest.approx(NOISE_LN / math.log(10), rel=0.15)
    assert diagnose_energy(*synthetic(k_c=k_c, seed=2))["outlier_rows"] == []
    many = np.arange(0, f.size, int(0.8 / MAX_OUTLIER_SHARE))  # 2.5 % of the rows, x10 each
    w = synthetic(k_c=k_c, seed=2)[2]
    w[many] *= 10.0
    with pytest.raises(EstimationError, match=r"rows lie more than a factor of 2 off .* \(first: t\.csv:2\): not glitches"):
        diagnose_energy(f, b, w, row_names=names)


@pytest.mark.parametrize("per_curve, bad", [(n, bad) for n in (6, 8, 12) for bad in ((1,), (0,), (3, 4), (0, 1))
                                             if n > 6 or len(bad) == 1])
def test_on_short_curves_the_bad_rows_are_found_and_only_they(per_curve, bad):
    """A review's cases: with 6-12 flux densities per frequency, a row x100 pulls its neighbours' curves
    so far that, judged all at once, they went with it and the curve had too few rows left to be judged
    (nothing was found); two side by side at the end took a good neighbour with them.  Two bad rows of
    six are beyond it: the four good ones are fewer than a curve needs to be judged (six)."""
    from hystbench.analysis.diagnosis.loss_separation import gross_outlier_rows

    rng = np.random.default_rng(per_curve)
    f = np.repeat(np.geomspace(5e4, 5e5, 20), per_curve)
    b = np.tile(np.geomspace(0.02, 0.3, per_curve), 20)
    w = (0.3 * (b / 0.1) ** 2.6 + 1e-4 * f * b**2) * np.exp(rng.normal(0.0, 0.01, f.size))
    rows = [2 * per_curve + k for k in bad]  # on the third frequency's curve
    w[rows] *= 100.0
    assert np.flatnonzero(gross_outlier_rows(f, b, w)).tolist() == rows


def test_every_curve_fitted_at_once_is_each_curve_refitted_without_its_row():
    """The screen's deviations, all curves in one solve, against the definition computed here curve by
    curve: a kept row's deviation from the quadratic refitted without it (numpy's polyfit), a dropped
    row's from the quadratic of the kept rows; NaN on a curve with fewer than six kept rows, a constant
    where a curve has one flux density (also written two ways, 0.3 and 0.1 * 3)."""
    from hystbench.analysis.diagnosis.loss_separation import _about_neighbours

    rng = np.random.default_rng(7)
    sizes = (6, 9, 14, 5, 8)  # the fourth has too few rows; in the fifth every row has one B
    group = np.repeat(np.arange(len(sizes)), sizes)
    b = np.concatenate([np.sort(rng.uniform(0.02, 0.3, n)) if k != 4 else np.where(np.arange(n) % 2, 0.3, 0.1 * 3)
                        for k, n in enumerate(sizes)])
    lb = np.log10(b)
    y = 2.5 * lb + 0.4 * lb**2 + 0.3 * group + rng.normal(0.0, 0.01, lb.size)
    keep = np.ones(lb.size, bool)
    keep[[7, 20]] = False  # the second and third curves each lose a row
    deleted, floor, _, gain = _about_neighbours(1e5 * (1 + group), b, 10.0**y, None, keep)
    expected, total, rows_left = np.full(lb.size, np.nan), 0.0, 0
    for k, n in enumerate(sizes):
        rows = np.flatnonzero((group == k) & keep)
        if rows.size < 6:
            continue
        degree = 0 if k == 4 else 2
        fit = np.polyfit(lb[rows], y[rows], degree)
        total += float(np.sum((y[rows] - np.polyval(fit, lb[rows])) ** 2))
        rows_left += rows.size - 3
        for i in np.flatnonzero(group == k):
            others = rows[rows != i]
            expected[i] = y[i] - np.polyval(np.polyfit(lb[others], y[others], degree), lb[i])
    assert np.array_equal(np.isnan(deleted), np.isnan(expected))
    assert deleted[~np.isnan(expected)] == pytest.approx(expected[~np.isnan(expected)], abs=1e-9)
    assert floor == pytest.approx(math.sqrt(total / rows_left), rel=1e-9)
    assert np.isnan(gain[[7, 20]]).all() and np.isnan(gain[group == 3]).all() and (gain[keep & (group != 3)] >= 0).all()


def test_a_row_that_alone_sets_its_curve_is_not_judged_and_a_tie_goes_to_the_row_furthest_off():
    """A review's cases.  A row alone near its own flux density (0.3003 T beside three rows at 0.3 T)
    fixes its curve's quadratic by itself: its deviation from the others is 0 / 0, and rounding had made
    good rows gross errors.  Two single rows whose removals lower the curve's misfit alike (either leaves
    a quadratic through three B): the one far off goes, whichever rounding favours."""
    from hystbench.analysis.diagnosis.loss_separation import gross_outlier_rows

    b_b = np.geomspace(0.02, 0.3, 8)
    for scale in (1e-12, 1.0, 1e12):
        for seed in range(5):
            rng = np.random.default_rng(seed)
            b = np.r_[[0.03] * 3 + [0.3] * 3 + [0.3003], b_b]
            w = scale * (b / 0.1) ** 2.5 * np.exp(rng.normal(0.0, 0.01, b.size))
            assert not gross_outlier_rows(np.r_[np.full(7, 1e5), np.full(8, 2e5)], b, w).any(), (scale, seed)
    f = np.full(8, 5e4)
    b = np.array([0.0137404, 0.1037528, 0.0137404, 0.0137404, 0.0109648, 0.1037528, 0.0137404, 0.6180164])
    for seed in range(20):  # rounding gave the good row at 0.011 T the larger gain on 8 of these 20
        w = 40.0 * (b / 0.0137404) ** 1.62 * np.exp(np.random.default_rng(seed).normal(0.0, 0.03, 8))
        w[7] *= 15.0  # about 1.2 log10 off the curve of the others
        assert np.flatnonzero(gross_outlier_rows(f, b, w)).tolist() == [7], seed


def test_no_row_of_the_vendored_tables_is_a_gross_outlier():
    """MagNet's tables as vendored (its own outlier flags dropped by the converter) lie within a factor
    of 1.8 of their neighbours' curves: the screen leaves every measured row in."""
    from hystbench.analysis.diagnosis.loss_separation import energy_table, gross_outlier_rows, loss_table_groups

    for group in loss_table_groups(sorted(REAL.glob("magnet_*.csv")) + [REAL / "N87_mu_large.csv"]):
        if group[0].kind == "core_loss":
            f, b, w, duty = energy_table(group)
            assert not gross_outlier_rows(f, b, w, duty).any(), group[0].path


def test_too_small_a_table_is_refused():
    f, b, w = synthetic()
    with pytest.raises(EstimationError, match="need >= 12 rows"):
        diagnose_energy(f[:5], b[:5], w[:5])


def test_an_off_grid_table_measures_its_scatter_about_a_smooth_surface():
    """Every row at its own frequency (no six flux densities share one): the noise floor comes from a
    smooth surface in log f and log B, and the classical term put in is named with its value."""
    rng = np.random.default_rng(5)
    f = np.exp(rng.uniform(np.log(50e3), np.log(500e3), 400))
    b = np.exp(rng.uniform(np.log(0.01), np.log(0.25), 400))
    w = (K_H * (b / 0.1) ** BETA + 1e-4 * f * b**2) * np.exp(rng.normal(0.0, NOISE_LN, f.size))
    r = diagnose_energy(f, b, w)
    assert r["effects"] == ["lamination_eddy_currents"]
    assert _within(r["parameters"]["lamination_eddy_currents"]["k_c_J_s_per_m3_T2"], 1e-4)
    # an upper bound (the surface's own misfit is in it), here within a fifth of the scatter put in
    assert 0.9 < r["noise_floor"]["log10_W"] / (NOISE_LN / math.log(10)) < 1.2


def test_a_table_with_too_few_frequencies_is_refused_and_a_falling_loss_is_said_to_fall(tmp_path: Path):
    """Three frequencies: the lowest third would be one, where every rate term is a constant (it said
    "nothing needed" of a table with eddy currents); five: calibrated on three, the interleaved split
    (every third frequency) not possible, and said so beside the figures.  A loss per cycle falling
    with f is said to fall."""
    rng = np.random.default_rng(2)

    def write(name: str, freqs: np.ndarray, scale=lambda f, b: 1e-4 * f * b**2) -> Path:
        f, b = (a.ravel() for a in np.meshgrid(freqs, np.geomspace(0.02, 0.25, 8), indexing="ij"))
        w = (K_H * (b / 0.1) ** BETA + scale(f, b)) * np.exp(rng.normal(0.0, NOISE_LN, f.size))
        path = tmp_path / f"{name}.csv"
        path.write_text("frequency_Hz,flux_density_peak_T,loss_W_per_m3\n"
                        + "".join(f"{x!r},{y!r},{z!r}\n" for x, y, z in zip(f.tolist(), b.tolist(), (w * f).tolist())))
        path.with_suffix(".json").write_text((REAL / "magnet_N87_sine.json").read_text())
        return path

    three = write("three", np.array([50e3, 100e3, 200e3]))
    with pytest.raises(EstimationError, match=r"three\.csv: split 'low_third': the table has 3 distinct frequencies"):
        diagnose_loss_table(three)
    r = diagnose_loss_table(write("five", np.geomspace(50e3, 400e3, 5)))
    assert r["rows"]["calibration_max_Hz"] == pytest.approx(50e3 * 8 ** 0.5)  # the third of five
    assert r["effects"] == ["lamination_eddy_currents"]
    assert "the table has 5 distinct frequencies" in r["other_split"]["refused"]
    # four: calibrated on three, one held out; the located grid is that one frequency (it was an empty
    # grid and a traceback)
    r = diagnose_loss_table(write("four", np.array([50e3, 100e3, 200e3, 400e3])))
    assert r["located"]["frequencies_Hz"] == pytest.approx([400e3]) and sum(map(sum, r["located"]["count"])) == 8
    falling = write("falling", np.geomspace(50e3, 500e3, 12), lambda f, b: 0.3 * (f / 1e5) ** -1.0 * (b / 0.1) ** 2)
    r = diagnose_loss_table(falling)
    assert r["located"]["trend"]["slope_log_f"] < 0 and "energy per cycle falls with frequency" in r["verdict"]


def test_a_held_out_band_far_above_a_narrow_calibration_band_is_said_to_be_beyond_it():
    """A datasheet-like table (20 frequencies 50-500 kHz, six flux densities, a Steinmetz law P = k f^1.5
    B^2.7): the lowest third is 50-92 kHz, a factor of 1.8, and the held-out rows reach 5.5x above it.
    What a rate term does that far is not in the band, and the verdict says so; calibrated across the
    band it is not said, nor on MagNet's grid (50-190 kHz held out to 500 kHz)."""
    rng = np.random.default_rng(3)
    f, b = (a.ravel() for a in np.meshgrid(np.round(np.geomspace(5e4, 5e5, 20), -2), np.geomspace(0.025, 0.2, 6),
                                           indexing="ij"))
    w = (f / 1e5) ** 0.5 * (b / 0.1) ** 2.7 * np.exp(rng.normal(0.0, NOISE_LN, f.size))  # J/m^3 per cycle
    narrow = diagnose_energy(f, b, w)
    top = np.unique(f)[5]  # the lowest third of 20 frequencies: six
    assert (f"span 50 kHz to {top / 1e3:.3g} kHz (a factor of {top / 5e4:.3g}) and the held-out rows reach "
            f"{5e5 / top:.3g}x above them") in narrow["verdict"]
    assert "the interleaved split calibrates across the band" in narrow["verdict"]
    few = np.isin(f, np.unique(f)[[0, 1, 2, 19]])  # four frequencies: no interleaved split to point to
    assert "held-out rows reach" in (v := diagnose_energy(f[few], b[few], w[few])["verdict"]) and "interleaved" not in v
    assert "held-out rows reach" not in diagnose_energy(f, b, w, split="interleaved")["verdict"]
    assert "held-out rows reach" not in diagnose_energy(*synthetic(k_c=1e-4))["verdict"]


def test_rows_repeated_exactly_are_said_to_overstate_the_evidence():
    """A table appended to itself: each of its rows twice (no vendored table repeats a row)."""
    f, b, w = (np.tile(a, 2) for a in synthetic(k_c=1e-4))
    r = diagnose_energy(f, b, w)
    assert r["repeated_rows"] == f.size // 2 and f"{f.size // 2} rows repeat another exactly" in r["verdict"]
    assert diagnose_energy(*synthetic(k_c=1e-4))["repeated_rows"] == 0


def test_a_zero_loss_is_refused_naming_its_line(tmp_path: Path):
    """The reader takes a loss of 0 (a physical bound); the diagnosis, on log(energy), names where it is."""
    lines = (REAL / "magnet_N87_sine.csv").read_text().splitlines()
    lines[7] = ",".join(lines[7].split(",")[:2] + ["0.0"])
    (tmp_path / "z.csv").write_text("\n".join(lines) + "\n")
    (tmp_path / "z.json").write_text((REAL / "magnet_N87_sine.json").read_text())
    with pytest.raises(RecordingError, match=r"z\.csv:8: column loss_W_per_m3: a loss of 0"):
        diagnose_loss_table(tmp_path / "z.csv")
    # a loss so small that its energy per cycle underflows to 0: named by its line too (it said only
    # "N87: energy per cycle must be finite and > 0 in every row")
    lines[7] = ",".join(lines[7].split(",")[:2] + ["1e-320"])
    (tmp_path / "z.csv").write_text("\n".join(lines) + "\n")
    with pytest.raises(RecordingError, match=r"z\.csv:8: the row's energy per cycle is 0\.0 J/m\^3"):
        diagnose_loss_table(tmp_path / "z.csv")


def _held_out_rms_direct(f: np.ndarray, b: np.ndarray, w: np.ndarray, train: np.ndarray, classical: bool) -> float:
    """An independent fit: W = sum_k a_k B^k (k = 2, 2.5, 3, 3.5) [+ a_c f B^2], linear least squares
    on relative errors (rows divided by W), held-out rms log10 error."""
    cols = [b**k for k in (2.0, 2.5, 3.0, 3.5)] + ([f * b**2] if classical else [])
    a = np.column_stack(cols)
    scale = np.abs(a[train] / w[train, None]).max(axis=0)
    coef = np.linalg.lstsq(a[train] / w[train, None] / scale, np.ones(train.sum()), rcond=None)[0] / scale
    pred = np.maximum(a @ coef, 1e-12)
    return float(np.sqrt(np.mean(np.log10(w[~train] / pred[~train]) ** 2)))


def _held_out_rms_series(f: np.ndarray, b: np.ndarray, w: np.ndarray, train: np.ndarray,
                         falling: bool = False) -> float:
    """An independent fit of a second-order rate series on sines, ln W = ln(k_h B^beta exp(c ln^2 B)
    + k_1 f B^d_1 + k_2 f^2 B^d_2 [+ k_f f^-g B^d_f]), by scipy's least squares in log space from a few
    starts; held-out rms log10 error."""
    from scipy.optimize import least_squares

    lf, lb = np.log(f / 1e5), np.log(b / 0.1)

    def model(x: np.ndarray, m: np.ndarray) -> np.ndarray:
        parts = [x[0] + x[1] * lb[m] + x[2] * lb[m] ** 2, x[3] + lf[m] + x[4] * lb[m], x[5] + 2 * lf[m] + x[6] * lb[m]]
        if falling:
            parts.append(x[7] - np.exp(x[8]) * lf[m] + x[9] * lb[m])
        return np.logaddexp.reduce(parts)

    y = np.log(w)
    extra = [-3.0, 0.0, 2.0] if falling else []
    fits = [least_squares(lambda x: model(x, train) - y[train], [0.0, 2.5, 0.0, k1, 2.5, k2, 2.5] + extra)
            for k1 in (-4.0, -1.0) for k2 in (-4.0, -1.0)]
    x = min(fits, key=lambda s: s.cost).x
    return float(np.sqrt(np.mean(((y[~train] - model(x, ~train)) / math.log(10)) ** 2)))


def test_n87_rate_dependent_term_named_and_held_out_error_shrinks():
    t = read_material_table(REAL / "magnet_N87_sine.csv")
    f, b = t.frequency_hz, t.flux_density_t
    w = t.columns["loss_W_per_m3"] / f
    train = f <= np.unique(f)[46 // 3 - 1]  # the lowest third of MagNet's 46 frequencies
    before = _held_out_rms_direct(f, b, w, train, classical=False)
    after = _held_out_rms_direct(f, b, w, train, classical=True)
    assert after < before / 1.5  # the direction, measured here without the tool
    series = _held_out_rms_series(f, b, w, train)
    assert series < after / 1.5  # a second order in the rate extrapolates better still (measured 0.041, 0.106)
    both = _held_out_rms_series(f, b, w, train, falling=True)
    assert both < series / 1.5  # with a loss per cycle falling with f beside it, better again (0.019, 0.041)
    r = diagnose_loss_table(REAL / "magnet_N87_sine.csv", split="low_third")
    # the library's rate series and falling term (not in the catalogue) are taken; a free Steinmetz term on
    # top of them is a suspect, its size undetermined.  Fitted on 50-190 kHz in the series' place, the free
    # term went to alpha ~3.8 and predicted 0.155 (1.55x)
    assert r["effects"] == ["rate_series", "falling_rate_dependence"] and r["not_in_catalogue"] == r["effects"]
    assert r["rows"]["calibration"] == int(train.sum())
    assert r["residual_before_log10"] == pytest.approx(before, rel=0.25)
    assert r["residual_after_log10"] == pytest.approx(both, rel=0.3)  # measured 0.019
    assert r["improvement"] > 10  # measured 12.8
    assert r["located"]["trend"]["slope_log_f"] > 0.3  # W per cycle grows with f
    assert r["other_split"]["improvement"] > 12  # the interleaved split: measured 18.2


def test_a_rate_term_whose_size_is_undetermined_is_a_suspect_not_a_finding():
    """N49's loss per cycle falls with f to about 140 kHz and rises above 190 kHz (docs/diagnosis.md).
    Fitted at 50-190 kHz the falling term is taken (the data do fall there); the rate terms beside it fit
    decisively with their sizes unresolved (relative standard error > 0.5: they trade with it and the
    baseline's B shape), so they are suspects, not findings.  Held out to 500 kHz the model then predicts
    worse than the baseline, and the verdict says so rather than leaving the name to speak."""
    r = diagnose_loss_table(REAL / "magnet_N49_sine.csv", split="low_third")
    assert r["effects"] == ["falling_rate_dependence"]
    sizes = {s["name"]: s["scale_rel_std"] for s in r["suspects"] if "scale_rel_std" in s}
    assert "rate_series" in sizes and min(sizes.values()) > 0.5
    assert "is not determined" in r["verdict"]
    assert r["residual_after_log10"] > r["residual_before_log10"]
    assert "predicts the held-out rows worse than the baseline" in r["verdict"]


def test_n87_permeability_energy_grows_with_frequency():
    """The second, independent view of N87: W = pi B^2 mu'' / (mu_0 |mu|^2) per cycle from the complex
    permeability, computed here; at every flux density measured at 10+ frequencies it grows with f."""
    t = read_material_table(REAL / "N87_mu_large.csv")
    mu = t.columns["mu_real"] - 1j * -t.columns["mu_imag"]
    w = math.pi * t.flux_density_t**2 * (-mu.imag) / (4e-7 * math.pi * np.abs(mu) ** 2)
    slopes = []
    for level in np.unique(t.flux_density_t):
        m = t.flux_density_t == level
        if m.sum() >= 10:
            slopes.append(np.polyfit(np.log(t.frequency_hz[m]), np.log(w[m]), 1)[0])
    assert len(slopes) > 20 and min(slopes) > 0
    r = diagnose_loss_table(REAL / "N87_mu_large.csv")
    assert r["effects"] and r["improvement"] > 1.25  # measured 1.48 (free Steinmetz term, alpha ~3.6)
    assert r["located"]["trend"]["slope_log_f"] > 0


def test_energy_per_cycle_refuses_shaped_rows_unless_told_they_are_carried(tmp_path):
    """A caller that reads W as a sine's (the figures) gets MagNet's duty-shaped rows refused by name;
    the diagnosis, which carries the duties into its shape factors, asks for them."""
    from hystbench.analysis.diagnosis.loss_separation import energy_per_cycle
    from hystbench.errors import RecordingError

    t = read_material_table(REAL / "magnet_N87_shapes.csv")
    with pytest.raises(RecordingError, match=r"magnet_N87_shapes\.csv: 24773 of 24773 rows are not sinusoidal"):
        energy_per_cycle(t)
    assert np.array_equal(energy_per_cycle(t, shapes=True), t.columns["loss_W_per_m3"] / t.frequency_hz)


# --- non-sinusoidal flux: MagNet's triangles and trapezoids (issue 28) ---------------------------------

def _real_duties() -> np.ndarray:
    return np.unique(read_material_table(REAL / "magnet_N87_shapes.csv").duty, axis=0)


def _integral_numerically(duty, p: float, n: int = 20_000) -> float:
    """int_0^1 |b'|^p from flux_shapes' B(t) on a grid holding every corner (tenths): the finite
    differences are the exact slopes of the piecewise-linear b."""
    from hystbench.formats.flux_shapes import shape_flux_density

    b = shape_flux_density(duty, 1.0, np.linspace(0.0, 1.0, n + 1))
    return float(np.sum(np.abs(np.diff(b) * n) ** p) / n)


@pytest.mark.parametrize("p", [1.2, 1.5, 2.0, 2.7])
def test_shape_factor_against_numerical_integration_and_the_triangle_closed_form(p: float):
    from hystbench.analysis.diagnosis.loss_shapes import shape_factor, sine_integral
    from hystbench.formats.flux_shapes import SINE_DUTY, shape_flux_density

    duties = _real_duties()
    assert len(duties) == 25
    s = shape_factor(duties, p)
    numeric = np.array([_integral_numerically(d, p) for d in duties]) / sine_integral(p)
    assert s == pytest.approx(numeric, rel=1e-9)
    tri = np.abs(duties[:, 1] + duties[:, 3]) < 1e-12
    d = duties[tri, 0]
    closed = 2.0**p * (d ** (1 - p) + (1 - d) ** (1 - p)) / sine_integral(p)
    assert s[tri] == pytest.approx(closed, rel=1e-12)
    # the sine's integral: its closed form against the derivative of flux_shapes' sine, numerically
    n = 200_000
    phase = (np.arange(n) + 0.5) / n
    assert np.mean(np.abs(2 * np.pi * np.cos(2 * np.pi * phase)) ** p) == pytest.approx(sine_integral(p), rel=1e-8)
    b = shape_flux_density(SINE_DUTY, 1.0, np.linspace(0, 1, n + 1))
    assert np.sum(np.abs(np.diff(b) * n) ** p) / n == pytest.approx(sine_integral(p), rel=1e-6)
    assert np.all(shape_factor(np.full((3, 4), -1.0), p) == 1.0)  # exactly: a sine's figures are unchanged


def test_a_selection_is_computed_once_and_each_caller_gets_its_own_copy(monkeypatch):
    """A report's figures draw the selection the diagnosis made a moment before: the same rows give the
    selection a fresh computation gives, computed once, and what one caller changes in its copy no
    other sees."""
    from hystbench.analysis.diagnosis import loss_separation
    from hystbench.analysis.diagnosis.loss_separation import _select_on_split, select_on_split
    from hystbench.analysis.diagnosis.loss_terms import Rows

    computed = []
    monkeypatch.setattr(loss_separation, "_SELECTIONS", {})  # what other tests left there is not this one's
    monkeypatch.setattr(loss_separation, "_select_on_split",
                        lambda *a: computed.append(a[2]) or _select_on_split(*a))

    f, b, w = synthetic(k_c=1e-4, seed=3)
    keep = np.isin(f, f[::60])  # every third frequency: the same physics on a third of the rows
    f, b, w = f[keep], b[keep], w[keep]
    first = select_on_split(Rows(f, b), w, "low_third", "sine_triangle")
    first[3].append("tampered")
    first[1][-1].x[:] = 0.0
    again = select_on_split(Rows(f.copy(), b.copy()), w.copy(), "low_third", "sine_triangle")
    fresh = _select_on_split(Rows(f, b), w, "low_third", "sine_triangle")
    assert again[3] == fresh[3] == ["lamination_eddy_currents"]
    assert np.array_equal(again[1][-1].x, fresh[1][-1].x) and np.array_equal(again[0], fresh[0])
    other = select_on_split(Rows(f, b), w, "interleaved", "sine_triangle")  # another split: its own selection
    assert not np.array_equal(other[0], fresh[0])
    assert computed == ["low_third", "interleaved"]  # the copy of the same rows came from the memo


def test_the_sine_diagnosis_is_unchanged_by_the_shape_path():
    """A sine table through the duty path (S_p = 1 on every row, sines calibrated on) gives today's
    figures to the last bit; one table given as a list is the same diagnosis."""
    t = read_material_table(REAL / "magnet_N87_sine.csv")
    f, b, w = t.frequency_hz, t.flux_density_t, t.columns["loss_W_per_m3"] / t.frequency_hz
    plain = diagnose_energy(f, b, w, material="N87")
    shaped = diagnose_energy(f, b, w, material="N87", duty=t.duty)
    assert "shapes" not in plain and set(shaped["shapes"]["groups"]) == {"sine"}
    for key in set(plain) - {"seconds", "verdict"}:
        assert json.dumps(plain[key], sort_keys=True) == json.dumps(shaped[key], sort_keys=True), key
    assert shaped["verdict"].startswith(plain["verdict"])
    one = diagnose_loss_table(REAL / "magnet_N87_sine.csv")
    listed = diagnose_loss_table([REAL / "magnet_N87_sine.csv"])
    for r in (one, listed):
        r.pop("seconds")
    assert json.dumps(one, sort_keys=True) == json.dumps(listed, sort_keys=True)


def synthetic_shapes(k_c: float, seed: int = 1):
    """The real 25 duty tuples and the sine x 46 frequencies x 10 flux densities, W = k_h (B/0.1)^beta
    + k_c f B^2 S_2, with 2 % scatter."""
    from hystbench.analysis.diagnosis.loss_shapes import shape_factor

    rng = np.random.default_rng(seed)
    shapes = np.vstack([np.full((1, 4), -1.0), _real_duties()])
    f0 = np.arange(50e3, 501e3, 10e3)
    b0 = np.geomspace(0.01, 0.25, 10)
    si, fi, bi = (a.ravel() for a in np.meshgrid(np.arange(len(shapes)), np.arange(f0.size), np.arange(b0.size),
                                                 indexing="ij"))
    duty, f = shapes[si], f0[fi]
    b = b0[bi] * np.exp(rng.uniform(-0.05, 0.05, f.size))
    w = K_H * (b / 0.1) ** BETA + k_c * f * b**2 * shape_factor(duty, 2.0)
    return f, b, w * np.exp(rng.normal(0.0, NOISE_LN, f.size)), duty


@pytest.mark.parametrize("seed", [1, 2])
def test_synthetic_shapes_name_the_classical_term_with_its_value_and_nothing_else(seed: int):
    k_c = 1e-4
    f, b, w, duty = synthetic_shapes(k_c, seed)
    r = diagnose_energy(f, b, w, duty=duty, split="low_third")
    assert r["effects"] == ["lamination_eddy_currents"]
    assert _within(r["parameters"]["lamination_eddy_currents"]["k_c_J_s_per_m3_T2"], k_c)
    assert _within(r["recalibrated"]["static_hysteresis.beta"], BETA)
    # calibrated on the sines and symmetric triangles of the lowest third only
    low = f <= np.unique(f)[46 // 3 - 1]
    sym = np.all(duty == -1, axis=1) | np.all(np.isclose(duty, [0.5, 0, 0.5, 0]), axis=1)
    assert r["rows"]["calibration"] == int((low & sym).sum())
    groups = r["shapes"]["groups"]
    assert set(groups) == {"sine", "triangle", "trapezoid"}
    for g in groups.values():  # every held-out shape predicted to the noise, far better than the baseline
        assert g["residual_after"] < 1.5 and g["improvement"] > 3
    assert r["noise_floor"]["log10_W"] == pytest.approx(NOISE_LN / math.log(10), rel=0.15)
    assert len(r["shapes"]["shapes"]) == 26
    json.dumps(r, allow_nan=False)


def test_real_n87_sine_and_shapes_are_diagnosed_together():
    """Structure only (the figures are measured, reported, not tuned into asserts)."""
    sine, shapes = REAL / "magnet_N87_sine.csv", REAL / "magnet_N87_shapes.csv"
    r = diagnose_loss_table([shapes, sine])  # any order: the sine table is read first
    assert r["paths"] == [str(sine), str(shapes)] and r["path"] == str(sine)
    ts, tt = read_material_table(sine), read_material_table(shapes)
    f = np.concatenate([ts.frequency_hz, tt.frequency_hz])
    duty = np.concatenate([ts.duty, tt.duty])
    low = f <= np.unique(f)[46 // 3 - 1]
    sym = np.all(duty == -1, axis=1) | np.all(np.isclose(duty, [0.5, 0, 0.5, 0]), axis=1)
    assert r["rows"]["calibration"] == int((low & sym).sum())
    assert r["rows"]["held_out"] == f.size - int((low & sym).sum())
    per = r["shapes"]["shapes"]
    assert len(per) == 26 and sum(s["held_out"] for s in per) == r["rows"]["held_out"]
    assert {s["group"] for s in per} == {"sine", "triangle", "trapezoid"}
    for s in per:
        assert all(math.isfinite(s[k]) for k in ("rms_before_log10", "rms_after_log10", "z_after"))
        if s["duty"][0] != -1 and not np.allclose(s["duty"], [0.5, 0, 0.5, 0]):
            assert s["held_out"] == int(np.all(np.isclose(tt.duty, s["duty"]), axis=1).sum())  # at every frequency
    for g in r["shapes"]["groups"].values():
        assert math.isfinite(g["residual_before"]) and math.isfinite(g["residual_after"])
    assert len(r["shapes"]["missed_most"]) == 3 and "missed most" in r["verdict"]
    for trend in ("between_ramps_trend", "flat_trend"):
        assert math.isfinite(r["shapes"][trend]["slope_log10_per_share"]) and r["shapes"][trend]["slope_std"] > 0
    assert set(r["other_split"]["shape_groups"]) == {"sine", "triangle", "trapezoid"}
    # the figures, as measured with margin (docs/diagnosis.md): low_third 3.22x (the rate series, not in
    # the catalogue; the free exponent on top of it is refused, it extrapolates worse inside the
    # calibration window), interleaved 6.37x (the series and the loss falling with f)
    assert r["improvement"] > 2.7 and r["effects"] == ["rate_series"]
    assert r["other_split"]["improvement"] > 5.5
    assert r["other_split"]["effects"] == ["rate_series", "falling_rate_dependence"]
    json.dumps(r, allow_nan=False)


def test_real_3e6_sine_and_shapes_held_out_figure():
    """3E6 (measured 19.9x, every shape group within 0.03 log10 after): the classical term carries it."""
    r = diagnose_loss_table([REAL / "magnet_3E6_sine.csv", REAL / "magnet_3E6_shapes.csv"])
    assert r["effects"] == ["lamination_eddy_currents"] and r["improvement"] > 12
    assert all(g["improvement"] > 8 for g in r["shapes"]["groups"].values())


def test_tables_of_two_materials_are_not_diagnosed_together_and_groups_pair_a_material():
    from hystbench.analysis.diagnosis.loss_separation import loss_table_groups
    from hystbench.errors import RecordingError

    with pytest.raises(RecordingError, match=r"magnet_3C90_shapes\.csv: core_loss table of '3C90'"):
        diagnose_loss_table([REAL / "magnet_N87_sine.csv", REAL / "magnet_3C90_shapes.csv"])
    names = ["magnet_N87_shapes", "N87_mu_large", "magnet_3E6_sine", "magnet_N87_sine"]
    groups = loss_table_groups([REAL / f"{n}.csv" for n in names])
    assert [[t.path.stem for t in g] for g in groups] == [["magnet_N87_sine", "magnet_N87_shapes"], ["N87_mu_large"],
                                                          ["magnet_3E6_sine"]]


def test_tables_measured_at_another_temperature_are_their_own_group_and_one_file_is_given_once(tmp_path):
    """A material's shapes table measured at 100 degC beside its sines at 25 degC: a ferrite's loss moves
    by a factor of two between them, so they are diagnosed apart (grouped together, a classical eddy
    current was named excess loss); 25 and 25.0 degC are one temperature; the same file twice is
    refused (its evidence would count twice)."""
    from hystbench.analysis.diagnosis.loss_separation import energy_table, loss_table_groups

    def copy(stem: str, name: str, **meta) -> Path:
        (tmp_path / f"{name}.csv").write_bytes((REAL / f"{stem}.csv").read_bytes())
        sidecar = json.loads((REAL / f"{stem}.json").read_text())
        (tmp_path / f"{name}.json").write_text(json.dumps({**sidecar, **meta}))
        return tmp_path / f"{name}.csv"

    sine = copy("magnet_N87_sine", "sine", temperature_C=25)
    hot = copy("magnet_N87_shapes", "hot", temperature_C=100.0)
    warm = copy("magnet_N87_shapes", "shapes", temperature_C=25.0)
    assert [[t.path.stem for t in g] for g in loss_table_groups([sine, hot])] == [["sine"], ["hot"]]
    assert [[t.path.stem for t in g] for g in loss_table_groups([sine, warm])] == [["sine", "shapes"]]
    with pytest.raises(RecordingError, match=r"hot\.json: temperature_C 100\.0, but .*sine\.json says 25"):
        energy_table([read_material_table(sine), read_material_table(hot)])
    with pytest.raises(RecordingError, match=r"sine\.csv: given twice"):
        loss_table_groups([sine, warm, tmp_path / "." / "sine.csv"])
