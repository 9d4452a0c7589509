"""Tests of the delay/phase estimators against injected truth (never against the code's output)."""

from __future__ import annotations

import doctest
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hystbench.analysis import estimation
from hystbench.analysis.estimation import (
    covariance_delay,
    delay_between,
    delay_crlb,
    estimation_errors,
    phase_delay,
    phase_difference_crlb,
    sine_fit,
    sine_snr,
)
from hystbench.analysis.estimation import covariance as covariance_module
from hystbench.analysis.estimation import crlb as crlb_module
from hystbench.analysis.estimation import sinefit as sinefit_module
from hystbench.errors import EstimationError

FS = 10_000.0  # Hz; 31.25 samples per period at 320 Hz, so records are not whole periods
F0 = 320.0  # nominal excitation (Hz)
F_TRUE = F0 * (1 + 30e-6)  # the generator's clock runs 30 ppm fast


def signal(n, *, freq=F_TRUE, delay_s=0.0, dc=0.0, parts=((1, 1.0, 0.4),), fs=FS):
    """dc + sum A_k cos(2 pi k f (t - delay - t_c) + phi_k); t_c the record centre."""
    t = np.arange(n) / fs - (n - 1) / (2 * fs) - delay_s
    return dc + sum(a * np.cos(2 * np.pi * k * freq * t + ph) for k, a, ph in parts)


def wrap(phi):
    return (phi + np.pi) % (2 * np.pi) - np.pi


# ---------------------------------------------------------------- noiseless recovery


@pytest.mark.parametrize(
    ("parts", "freq", "fit_freq"),
    [
        (((1, 2.0, 0.3),), F0, False),  # three-parameter fit at the exact frequency
        (((1, 2.0, 0.3),), F_TRUE, True),  # four-parameter, off-nominal
        (((2, 1.5, -2.0),), F_TRUE, True),  # E-core force without magnet: only 2f
        (((1, 1.0, 1.0), (2, 0.3, -0.5), (3, 0.05, 2.5)), F_TRUE, True),  # distorted sine
    ],
)
def test_sine_fit_recovers_noiseless_parameters(parts, freq, fit_freq):
    n = 1000
    x = signal(n, freq=freq, dc=0.75, parts=parts)
    fit = sine_fit(x, FS, F0, harmonics=[k for k, _, _ in parts], fit_freq=fit_freq)
    assert fit.converged
    assert fit.t_ref_s == pytest.approx((n - 1) / (2 * FS))
    assert fit.frequency_hz == pytest.approx(freq, rel=1e-12)
    assert fit.offset == pytest.approx(0.75, abs=1e-10)
    for k, amp, ph in parts:
        comp = fit.component(k)
        assert comp.amplitude == pytest.approx(amp, rel=1e-9)
        assert comp.phase_rad == pytest.approx(ph, abs=1e-9)
        assert comp.phase_se_rad < 1e-9
    assert fit.noise_std < 1e-10


def test_sine_fit_works_record_by_record_along_axis():
    phases = np.array([-3.0, -1.0, 0.5, 2.9])
    x = np.stack([signal(700, parts=((1, 1.0, p),)) for p in phases], axis=1)  # time on axis 0
    fit = sine_fit(x, FS, F0, axis=0)
    assert fit.phase_rad.shape == (4, 1)
    np.testing.assert_allclose(fit.phase_rad[:, 0], phases, atol=1e-9)
    np.testing.assert_allclose(fit.frequency_hz, F_TRUE, rtol=1e-12)


def test_sine_fit_starts_from_the_spectrum_without_a_nominal_frequency():
    fit = sine_fit(signal(900, freq=F_TRUE, parts=((1, 1.0, -0.7),)), FS, None)
    assert fit.frequency_hz == pytest.approx(F_TRUE, rel=1e-12)
    assert fit.phase_rad[0] == pytest.approx(-0.7, abs=1e-9)


def test_gauss_newton_alone_converges_from_most_of_a_bin_away():
    n = 2000  # bin fs/n = 5 Hz
    fit = sine_fit(signal(n, freq=F_TRUE, parts=((1, 1.0, 0.2),)), FS, F_TRUE + 0.8 * FS / n, search_ppm=0)
    assert fit.converged
    assert fit.frequency_hz == pytest.approx(F_TRUE, rel=1e-12)


def test_long_record_far_off_nominal_is_found_by_the_start_search():
    n, f_true = 20_000, F0 * (1 + 3000e-6)  # 0.96 Hz off: two bins of a 2 s record
    x = signal(n, freq=f_true, parts=((1, 1.0, 0.2),))
    fit = sine_fit(x, FS, F0, search_ppm=5000)
    assert fit.frequency_hz == pytest.approx(f_true, rel=1e-12)
    assert fit.phase_rad[0] == pytest.approx(0.2, abs=1e-9)


@pytest.mark.parametrize("delay_samples", [0.37, 2.71, -1.3, 12.5])
def test_phase_delay_recovers_fractional_delays_exactly(delay_samples):
    d = delay_samples / FS
    x = signal(800, dc=0.2, parts=((1, 1.0, 0.9),))
    y = signal(800, dc=-3.0, delay_s=d, parts=((1, 0.01, 0.9),))  # tiny amplitude, DC offset
    r = phase_delay(x, y, FS, F0)
    assert r.delay_s == pytest.approx(d, abs=1e-13)
    assert r.phase_rad == pytest.approx(2 * np.pi * F_TRUE * d, abs=1e-9)
    assert r.frequency_hz == pytest.approx(F_TRUE, rel=1e-12)
    assert r.x.frequency_hz == r.y.frequency_hz


@pytest.mark.parametrize("harmonic", [1, 2, 3])
def test_phase_delay_of_a_distorted_waveform_is_the_same_at_every_harmonic(harmonic):
    d = 1.83 / FS  # 2 pi 3 f d < pi: no wrapping at the third harmonic
    parts = ((1, 1.0, 0.1), (2, 0.4, 2.0), (3, 0.1, -1.0))
    x = signal(1200, dc=1.0, parts=parts)
    y = signal(1200, dc=5.0, delay_s=d, parts=parts)
    r = phase_delay(x, y, FS, F0, harmonic=harmonic, harmonics=(1, 2, 3))
    assert r.harmonic == harmonic
    assert r.delay_s == pytest.approx(d, abs=1e-13)
    assert r.phase_rad == pytest.approx(2 * np.pi * harmonic * F_TRUE * d, abs=1e-9)


def test_phase_delay_at_twice_the_excitation_force_vs_squared_flux():
    """E-core without magnet: force ~ flux^2, both at 2f with a DC part."""
    d = 4.2 / FS
    flux = signal(1500, parts=((1, 1.0, 0.0),))
    force = signal(1500, delay_s=d, parts=((1, 1.0, 0.0),)) ** 2  # delayed copy of flux^2
    r = phase_delay(flux**2, force, FS, F0, harmonic=2)
    assert r.delay_s == pytest.approx(d, abs=1e-13)
    assert r.x.offset == pytest.approx(0.5, abs=1e-9)


# ---------------------------------------------------------------- statistics


def test_standard_errors_match_the_spread_over_noisy_trials():
    """400 trials: a sample standard deviation is then known to 1/sqrt(2*399) = 3.5 %, so 12 %
    (3.4 standard errors) separates a wrong standard error from chance; the means are checked to
    4 standard errors of the mean."""
    m, n, eta = 400, 500, 10 ** (30 / 10)
    rng = np.random.default_rng(20130705)
    d = 2.37 / FS
    phi0 = rng.uniform(-np.pi, np.pi, (m, 1))
    t = np.arange(n) / FS
    sig = 1 / math.sqrt(2 * eta)
    x = np.cos(2 * np.pi * F_TRUE * t + phi0) + 0.3 + sig * rng.standard_normal((m, n))
    y = 2 * np.cos(2 * np.pi * F_TRUE * (t - d) + phi0) + 2 * sig * rng.standard_normal((m, n))
    r = phase_delay(x, y, FS, F0)
    assert np.all(r.x.converged)
    err = r.delay_s - d
    bound = math.sqrt(delay_crlb(n, eta, eta, F_TRUE))
    assert abs(err.mean()) < 4 * bound / math.sqrt(m)
    assert err.std(ddof=1) == pytest.approx(np.mean(r.delay_se_s), rel=0.12)
    assert err.std(ddof=1) == pytest.approx(bound, rel=0.12)
    assert np.mean(r.delay_se_s) == pytest.approx(bound, rel=0.05)  # 5 %: se is a smooth estimate
    assert r.phase_rad.std(ddof=1) == pytest.approx(np.mean(r.phase_se_rad), rel=0.12)
    # single-channel errors: amplitude, frequency and noise level
    fit = r.x
    assert fit.amplitude[:, 0].std(ddof=1) == pytest.approx(np.mean(fit.amplitude_se[:, 0]), rel=0.12)
    assert fit.frequency_hz.std(ddof=1) == pytest.approx(np.mean(fit.frequency_se_hz), rel=0.12)
    assert abs(fit.frequency_hz.mean() - F_TRUE) < 4 * np.mean(fit.frequency_se_hz) / math.sqrt(m)
    assert np.mean(fit.noise_std) == pytest.approx(sig, rel=0.01)


# ---------------------------------------------------------------- covariance method (Eq. 3)


@pytest.mark.parametrize(("delay_samples", "expected_lag"), [(3, 3), (-4, -4), (0, 0), (2.4, 2), (2.6, 3), (-7.3, -7)])
def test_covariance_delay_is_quantised_to_the_nearest_sample(delay_samples, expected_lag):
    x = signal(2000, dc=0.5, parts=((1, 1.0, 0.2),))
    y = signal(2000, dc=-1.0, delay_s=delay_samples / FS, parts=((1, 3.0, 0.2),))
    r = covariance_delay(x, y, FS, F0)
    assert r.lag_samples == expected_lag
    assert r.delay_s == pytest.approx(expected_lag / FS)
    assert r.phase_rad == pytest.approx(2 * np.pi * F0 * expected_lag / FS)
    assert r.lags[0] == -15 and r.lags[-1] == 15  # one period, round(fs / f) = 31 lags


def test_covariance_delay_of_squared_flux_uses_the_signal_period():
    flux = signal(3000, parts=((1, 1.0, 0.0),))
    force = signal(3000, delay_s=5 / FS, parts=((1, 1.0, 0.0),)) ** 2
    r = covariance_delay(flux**2, force, FS, 2 * F0)
    assert r.lag_samples == 5


def test_covariance_delay_batched():
    lags = [1, -2, 6]
    y = np.stack([signal(1000, delay_s=k / FS) for k in lags])
    r = covariance_delay(np.broadcast_to(signal(1000), y.shape), y, FS, F0)
    np.testing.assert_array_equal(r.lag_samples, lags)


# ---------------------------------------------------------------- bounds


def test_crlb_values():
    assert sine_snr(2.0, 0.5) == pytest.approx(8.0)
    assert phase_difference_crlb(100, 10.0, 40.0) == pytest.approx(1 / 1000 + 1 / 4000)
    assert phase_difference_crlb(100, 10.0, np.inf) == pytest.approx(1 / 1000)
    assert delay_crlb(100, 10.0, 40.0, 50.0, harmonic=2) == pytest.approx((1 / 1000 + 1 / 4000) / (200 * np.pi) ** 2)
    np.testing.assert_allclose(phase_difference_crlb(np.array([10, 20]), 1.0, 1.0), [0.2, 0.1])


@pytest.mark.parametrize(
    ("call", "name"),
    [
        (lambda: phase_difference_crlb(0, 1.0, 1.0), "n"),
        (lambda: phase_difference_crlb(10.5, 1.0, 1.0), "n"),
        (lambda: phase_difference_crlb(10, 0.0, 1.0), "eta_x"),
        (lambda: phase_difference_crlb(10, 1.0, np.nan), "eta_y"),
        (lambda: delay_crlb(10, 1.0, 1.0, -5.0), "frequency_hz"),
        (lambda: delay_crlb(10, 1.0, 1.0, 5.0, harmonic=0), "harmonic"),
        (lambda: sine_snr(-1.0, 1.0), "amplitude"),
        (lambda: sine_snr(1.0, 0.0), "noise_std"),
    ],
)
def test_crlb_rejects_bad_arguments(call, name):
    with pytest.raises(ValueError, match=rf"^{name}\b"):
        call()


# ---------------------------------------------------------------- bad input

GOOD = signal(400)
SHORT = signal(62)  # two periods are 62.5 samples


def _bad_cases():
    nan, inf = GOOD.copy(), GOOD.copy()
    nan[17], inf[3] = np.nan, -np.inf
    flat = np.full_like(GOOD, 0.3)
    cases = {
        "fs zero": (dict(fs_hz=0.0), "fs_hz"),
        "fs negative": (dict(fs_hz=-FS), "fs_hz"),
        "fs nan": (dict(fs_hz=np.nan), "fs_hz"),
        "fs text": (dict(fs_hz="fast"), "fs_hz"),
        "freq above nyquist": (dict(frequency_hz=6000.0), "frequency_hz"),
        "freq at nyquist": (dict(frequency_hz=FS / 2), "frequency_hz"),
        "freq zero": (dict(frequency_hz=0.0), "frequency_hz"),
        "freq inf": (dict(frequency_hz=np.inf), "frequency_hz"),
        "x short": (dict(x=SHORT, y=SHORT), "x"),
        "x nan": (dict(x=nan), "x"),
        "y inf": (dict(y=inf), "y"),
        "x flat": (dict(x=flat), "x"),
        "y flat": (dict(y=flat), "y"),
        "y longer": (dict(y=signal(401)), "y"),
        "x complex": (dict(x=GOOD.astype(complex)), "x"),
        "x scalar": (dict(x=1.0), "x"),
        "x boolean": (dict(x=GOOD > 0), "x"),
    }
    return cases


def _call(func, x=GOOD, y=GOOD, fs_hz=FS, frequency_hz=F0, **kw):
    if func is sine_fit:
        return sine_fit(x, fs_hz, frequency_hz, **kw)
    return func(x, y, fs_hz, frequency_hz, **kw)


@pytest.mark.parametrize(
    ("func", "case"),
    [
        pytest.param(func, case, id=f"{func.__name__}-{case}")
        for func in (sine_fit, phase_delay, covariance_delay)
        for case, (_, name) in _bad_cases().items()
        if not (func is sine_fit and name == "y")  # sine_fit has one channel
    ],
)
def test_bad_input_raises_value_error_naming_the_parameter(func, case):
    kwargs, name = _bad_cases()[case]
    with pytest.raises(ValueError, match=rf"\b{name}\b"):
        _call(func, **kwargs)


@pytest.mark.parametrize(
    ("kwargs", "name"),
    [
        (dict(harmonics=(1, 16)), "frequency_hz"),  # 16 x 320 Hz is above fs/2
        (dict(harmonics=(0,)), "harmonics"),
        (dict(harmonics=(1, 1)), "harmonics"),
        (dict(harmonics=()), "harmonics"),
        (dict(max_iter=0), "max_iter"),
        (dict(tol=0.0), "tol"),
        (dict(tol="small"), "tol"),
        (dict(search_ppm=-1.0), "search_ppm"),
        (dict(fit_freq=False, frequency_hz=None), "frequency_hz"),
        (dict(axis=3), "axis"),
    ],
)
def test_sine_fit_rejects_bad_options(kwargs, name):
    with pytest.raises(ValueError, match=rf"\b{name}\b"):
        _call(sine_fit, **kwargs)


@pytest.mark.parametrize(
    "kwargs", [dict(harmonic=2, harmonics=(1,)), dict(harmonic=2, harmonics=(1, 3)), dict(harmonic=0), dict(harmonic=1.0)]
)
def test_phase_delay_rejects_a_harmonic_it_does_not_fit(kwargs):
    with pytest.raises(ValueError, match=r"^harmonic\b"):
        phase_delay(GOOD, GOOD, FS, F0, **kwargs)


@pytest.mark.parametrize("harmonic", [1, 2])
def test_delay_between_two_fits_is_the_joint_fits_delay_at_that_frequency(harmonic):
    # at a given frequency two channels share no parameter: fitting them apart and reading the
    # delay off both fits must give the joint fit's delay and standard error
    rng = np.random.default_rng(3)
    t = np.arange(3001) / FS
    d = 37e-6

    def wave(a1, a2, delay):
        return a1 * np.cos(2 * np.pi * F0 * (t - delay)) + a2 * np.cos(4 * np.pi * F0 * (t - delay) + 0.4)

    x = wave(1.0, 0.3, 0.0) + 0.01 * rng.standard_normal(t.size)
    y = wave(2.0, 0.5, d) + 0.02 * rng.standard_normal(t.size)
    hs = (1, 2, 3)
    joint = phase_delay(x, y, FS, F0, harmonic=harmonic, harmonics=hs, fit_freq=False)
    apart = delay_between(sine_fit(x, FS, F0, harmonics=hs, fit_freq=False),
                          sine_fit(y, FS, F0, harmonics=hs, fit_freq=False), harmonic)
    assert apart.delay_s == pytest.approx(joint.delay_s, rel=1e-10)
    assert apart.delay_se_s == pytest.approx(joint.delay_se_s, rel=1e-9)
    assert apart.phase_rad == pytest.approx(joint.phase_rad, rel=1e-10)
    assert apart.delay_s == pytest.approx(d, abs=5 * apart.delay_se_s)


def test_delay_between_refuses_fits_at_different_frequencies():
    with pytest.raises(ValueError, match="different frequencies"):
        delay_between(sine_fit(GOOD, FS, F0, fit_freq=False), sine_fit(GOOD, FS, F0 * 1.0001, fit_freq=False), 1)


def test_component_rejects_an_unfitted_harmonic():
    with pytest.raises(ValueError, match="harmonic 2"):
        sine_fit(GOOD, FS, F0).component(2)


def test_estimation_errors_name_the_recording():
    with pytest.raises(EstimationError, match=r"^bench/run_7\.csv: y has shape") as info:
        with estimation_errors("bench/run_7.csv"):
            phase_delay(GOOD, GOOD[:-1], FS, F0)
    assert isinstance(info.value.__cause__, ValueError)


# ---------------------------------------------------------------- properties, speed, docs


@settings(max_examples=25, deadline=None)
@given(
    scale_x=st.floats(1e-3, 1e3),
    scale_y=st.floats(-1e3, 1e3).filter(lambda v: abs(v) > 1e-3),
    dc_x=st.floats(-1e3, 1e3),
    dc_y=st.floats(-1e3, 1e3),
)
def test_delay_is_invariant_under_gain_and_offset(scale_x, scale_y, dc_x, dc_y):
    """Affine maps of either channel leave the delay unchanged (a negative gain flips y by pi)."""
    rng = np.random.default_rng(7)
    x0 = signal(600, parts=((1, 1.0, 0.3),)) + 0.01 * rng.standard_normal(600)
    y0 = signal(600, delay_s=3.3 / FS, parts=((1, 1.0, 0.3),)) + 0.02 * rng.standard_normal(600)
    base = phase_delay(x0, y0, FS, F0)
    moved = phase_delay(scale_x * x0 + dc_x, scale_y * y0 + dc_y, FS, F0)
    shift = 0.0 if scale_y > 0 else np.pi
    assert wrap(moved.phase_rad - base.phase_rad - shift) == pytest.approx(0.0, abs=1e-4 * base.phase_se_rad)
    assert moved.phase_se_rad == pytest.approx(base.phase_se_rad, rel=1e-6)


def test_a_100k_sample_record_fits_to_its_delay():
    """Speed is the benchmarks' business (``python -m benchmarks estimation_stage`` times these fits on the
    live windows); CI times nothing."""
    x = signal(100_000, parts=((1, 1.0, 0.3),)) + 0.01 * np.random.default_rng(3).standard_normal(100_000)
    y = signal(100_000, delay_s=1e-4, parts=((1, 1.0, 0.3),))
    assert phase_delay(x, y, FS, F0).delay_s == pytest.approx(1e-4, abs=1e-8)


@pytest.mark.parametrize("module", [estimation, sinefit_module, covariance_module, crlb_module], ids=lambda m: m.__name__)
def test_docstring_examples(module):
    result = doctest.testmod(module, optionflags=doctest.ELLIPSIS)
    assert result.failed == 0
