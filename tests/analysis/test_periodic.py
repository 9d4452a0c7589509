"""The one period averager and the one frequency estimator, against signals defined in closed form."""

import numpy as np
import pytest
from scipy.interpolate import CubicSpline

from hystbench.analysis import periodic
from hystbench.analysis.periodic import estimate_frequency, period_average, synchronous_average
from hystbench.errors import EstimationError
from hystbench.formats.recording import Recording

FS = 10_000.0
F = 97.3  # 102.77... samples per period: no whole number of samples fits one
HARMONICS = {1: (1.0, 0.3), 2: (0.25, -1.1), 5: (0.04, 0.7)}  # k: (amplitude, phase at t = 0)
OFFSET = 0.6


def signal(t, f=F):
    return OFFSET + sum(a * np.sin(2 * np.pi * k * f * t + p) for k, (a, p) in HARMONICS.items())


def spline_bound(f=F, fs=FS):
    """Largest error of cubic-spline interpolation of :func:`signal`: 5/384 h^4 max|x''''|, with
    max|x''''| <= sum a_k (2 pi k f)^4 (de Boor's bound for the complete spline, ample here)."""
    return 5 / 384 * (1 / fs) ** 4 * sum(a * (2 * np.pi * k * f) ** 4 for k, (a, _) in HARMONICS.items())


def test_recovers_a_periodic_signal_at_a_non_integer_number_of_samples_per_period():
    t = np.arange(int(0.5 * FS)) / FS
    avg = period_average({"x": signal(t)}, FS, F, 400)
    assert avg.periods == 48  # 0.4999 s x 97.3 Hz: 48.6 periods, the whole ones
    expected = signal(avg.phase / F)  # phase 0 is sample 0
    bound = spline_bound()
    assert 1e-7 < bound < 1e-4  # the test means something: a loose average would miss by far more
    assert np.max(np.abs(avg.channels["x"] - expected)) < bound
    # every periodic component cancels in the alternating average (48 periods: an even number)
    assert np.max(np.abs(avg.alternating["x"])) < bound
    assert avg.noise_rms["x"] < bound  # no noise: every period is the average


def test_noise_is_averaged_and_measured():
    rng = np.random.default_rng(4)
    sigma = 0.05
    t = np.arange(int(2.0 * FS)) / FS
    avg = period_average({"x": signal(t) + sigma * rng.standard_normal(t.size)}, FS, F, 200)
    p = avg.periods
    assert p == 194
    # the cubic spline through noisy samples smooths between them: the rms of one resampled period
    # about the average is the noise's, a little lower (interpolated points average neighbours)
    assert 0.75 * sigma < avg.noise_rms["x"] < sigma
    left = avg.channels["x"] - signal(avg.phase / F)  # what averaging 194 periods leaves of the noise
    assert np.std(left) == pytest.approx(avg.noise_rms["x"] / np.sqrt(p), rel=0.1)
    assert np.std(avg.alternating["x"]) == pytest.approx(np.std(left), rel=0.15)  # the floor is that noise


def test_long_records_go_in_chunks_with_the_same_result(monkeypatch):
    """Bounded memory: the spline is built and evaluated a few periods at a time; the result is the
    average of a spline through the whole record (the oracle below, computed at once)."""
    rng = np.random.default_rng(5)
    t = np.arange(int(1.0 * FS)) / FS
    x = signal(t * (1 + 30e-6)) + 0.01 * rng.standard_normal(t.size)
    f = F * (1 + 30e-6)
    n_points = 64
    periods = int(np.floor(t[-1] * f + 1e-9))
    when = (np.arange(periods)[:, None] + np.arange(n_points)[None, :] / n_points) / f
    grid = CubicSpline(t, x)(when)
    even = periods - periods % 2
    alt = (grid[:even] * np.where(np.arange(even) % 2 == 0, 1.0, -1.0)[:, None]).mean(axis=0)
    monkeypatch.setattr(periodic, "CHUNK_VALUES", 7 * n_points)  # 7 periods a chunk, 14 chunks
    avg = period_average({"x": x}, FS, f, n_points)
    assert avg.periods == periods == 97
    assert avg.channels["x"] == pytest.approx(grid.mean(axis=0), abs=1e-12)
    assert avg.alternating["x"] == pytest.approx(alt, abs=1e-12)
    assert avg.noise_rms["x"] == pytest.approx(np.sqrt(np.mean((grid - grid.mean(axis=0)) ** 2)), rel=1e-9)


def test_frequency_within_the_cramer_rao_bound():
    rng = np.random.default_rng(6)
    f_true, sigma, n = 320.0 * (1 + 25e-6), 0.01, 25_000
    fs = 100_000.0
    t = np.arange(n) / fs
    x = np.sin(2 * np.pi * f_true * t + 0.4) + 0.2 * np.sin(4 * np.pi * f_true * t) + sigma * rng.standard_normal(n)
    # the bound for the fundamental alone (Kay: var f = 6 sigma^2 / (pi^2 A^2 N T^2)); the 2nd
    # harmonic only adds information
    crlb = np.sqrt(6 * sigma**2 / (np.pi**2 * n * (n / fs) ** 2))
    assert abs(estimate_frequency(x, fs, 320.0) - f_true) < 4 * crlb
    assert abs(320.0 - f_true) > 30 * crlb  # the nominal frequency would be far off


def test_bad_input_names_the_parameter_or_the_recording():
    x = signal(np.arange(50) / FS)  # half a period
    with pytest.raises(ValueError, match="shorter than one period of 97.3 Hz"):
        period_average({"x": x}, FS, F)
    with pytest.raises(ValueError, match="n_points"):
        period_average({"x": signal(np.arange(1000) / FS)}, FS, F, 4)
    with pytest.raises(ValueError, match="no channel 'y'"):
        period_average({"x": x}, FS, F, names=("y",))
    rec = Recording(None, FS, {"current_A": x}, {"rig": "ecore_pm", "frequency_Hz": F, "current_pp_A": 1.0})
    with pytest.raises(EstimationError, match="ecore_pm recording at 97.3 Hz.*shorter than one period"):
        synchronous_average(rec, F)
