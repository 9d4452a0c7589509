"""Period tables: spectral helpers and the live meter (frequency, alignment to the table, floor)."""

import numpy as np
import pytest

from hystbench.analysis.periodic import estimate_frequency
from hystbench.compensator.periodic import apply_response, denoise, derivative, measure_period, resample, shift

PH = np.arange(400) / 400


def test_derivative_and_shift():
    x = np.sin(2 * np.pi * PH) + 0.2 * np.cos(2 * np.pi * 3 * PH)
    dx = 2 * np.pi * 50 * (np.cos(2 * np.pi * PH) - 0.6 * np.sin(2 * np.pi * 3 * PH))
    assert derivative(x, 50.0) == pytest.approx(dx, abs=1e-9)
    assert shift(np.sin(2 * np.pi * PH), 0.25) == pytest.approx(-np.cos(2 * np.pi * PH), abs=1e-12)
    assert resample(x, 1000)[::5] == pytest.approx(x[::2], abs=1e-12)


def test_response_and_its_band_limited_inverse():
    lag = lambda f: 1.0 / (1.0 + 1j * np.asarray(f) / 2000.0)  # noqa: E731 - a first-order low-pass
    x = 1.0 + np.sin(2 * np.pi * PH) + 0.1 * np.sin(2 * np.pi * 7 * PH)
    y = apply_response(x, 320.0, lag)
    assert y[0] != pytest.approx(x[0], abs=1e-3)  # the 7th harmonic at 2.24 kHz is attenuated and delayed
    assert apply_response(y, 320.0, lag, inverse=True) == pytest.approx(x, abs=1e-12)
    first = apply_response(y, 320.0, lag, inverse=True, max_harmonic=1)
    assert first == pytest.approx(1.0 + np.sin(2 * np.pi * PH), abs=1e-12)


def test_denoise_drops_only_the_noise():
    rng = np.random.default_rng(1)
    clean = 0.6 * np.sin(2 * np.pi * PH) + 1e-3 * np.sin(2 * np.pi * 5 * PH)
    noisy = clean + 1e-5 * rng.standard_normal(PH.size)
    out = denoise(noisy, 1e-5)
    assert np.max(np.abs(out - clean)) < 0.3 * np.max(np.abs(noisy - clean))
    assert denoise(noisy, float("nan")) == pytest.approx(noisy)


def _played(table, fs, f_true, start_cycles, n, noise, rng):
    """A generator playing ``table`` (linear interpolation) from ``start_cycles``, as the rig does."""
    cyc = np.mod(start_cycles + f_true / fs * np.arange(n), 1.0)
    grid = np.arange(table.size + 1) / table.size
    return np.interp(cyc, grid, np.append(table, table[0])) + noise * rng.standard_normal(n)


def test_meter_finds_frequency_phase_and_floor():
    rng = np.random.default_rng(2)
    fs, f_nom = 100_000.0, 320.0
    f_true = f_nom * (1 + 25e-6)
    table = 0.3 + 0.5 * np.sin(2 * np.pi * PH) + 0.05 * np.sin(2 * np.pi * 2 * PH + 1.0)
    force = 170 + 40 * np.sin(2 * np.pi * PH - 0.3)
    n = 25_000
    chans = {"command_V": _played(table / 0.5, fs, f_true, 0.37, n, 1e-4, rng),
             "force_N": _played(force, fs, f_true, 0.37, n, 0.03, rng)}
    f_est = estimate_frequency(chans["command_V"], fs, f_nom)
    assert f_est == pytest.approx(f_true, rel=2e-7)
    m = measure_period(chans, fs, f_est, table, n_points=400)
    assert m.periods == 79  # whole periods inside the record
    assert m.channels["command_V"] * 0.5 == pytest.approx(table, abs=2e-4)  # aligned to the table
    assert np.max(np.abs(m.channels["force_N"] - force)) < 0.02
    expected_rms = 0.03 / np.sqrt(78)  # the alternating average uses an even number
    assert 2.0 * expected_rms < m.floor("force_N") < 5.0 * expected_rms  # max of ~400 Gaussian points
