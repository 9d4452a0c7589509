"""Features of synthetic recordings whose harmonics, drift, lines and noise are known, plus one
simulated E-core recording checked against physics (flux lags current)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.signal import lfilter

from hystbench.analysis.diagnosis.features import record_features, spline_gain
from hystbench.formats.recording import Recording
from hystbench.sim_backend.recordings import simulate_recording

META = {"rig": "ecore_pm", "current_pp_A": 1.4}


def _signal(t: np.ndarray, f: float, mean: float, amps: dict[int, complex], phase0: float) -> np.ndarray:
    """mean + sum Re(X_k e^{ik(wt + phase0)}): X_k given relative to a current of phase phase0."""
    x = np.full(t.size, mean)
    for k, a in amps.items():
        x += np.real(a * np.exp(1j * k * (2 * np.pi * f * t + phase0)))
    return x


def _recording(fs: float, f: float, duration: float, *, seed: int = 0, phase0: float = 0.4, drift: float = 0.0,
               line: complex = 0.0, sigma: float = 0.01, sigma_i: float = 1e-5, extra: dict | None = None) -> Recording:
    t = np.arange(int(round(fs * duration))) / fs
    rng = np.random.default_rng(seed)
    current = _signal(t, f, 0.0, {1: 0.7, 3: 0.05 * np.exp(1j)}, phase0) + sigma_i * rng.standard_normal(t.size)
    flux = (_signal(t, f, 0.1, {1: 2 * np.exp(-0.3j), 2: 0.3 * np.exp(0.5j), 5: 0.04j}, phase0)
            + drift * t + np.real(line * np.exp(2j * np.pi * 50.0 * t)) + sigma * rng.standard_normal(t.size))
    channels = {"current_A": current, "flux_Wb": flux, **(extra or {})}
    return Recording(None, fs, channels, {**META, "frequency_Hz": f, "sample_rate_Hz": fs})


TRUTH = {"current_A": {0: 0.0, 1: 0.7, 2: 0.0, 3: 0.05 * np.exp(1j)},
         "flux_Wb": {1: 2 * np.exp(-0.3j), 2: 0.3 * np.exp(0.5j), 3: 0.0, 4: 0.0, 5: 0.04j, 6: 0.0, 7: 0.0}}


def _check_harmonics(feat, truth: dict[str, dict[int, complex]], z: float = 4.5) -> None:
    for ch, want in truth.items():
        for k, x in want.items():
            got, se = feat.harmonics[ch][k], feat.se[ch][k]
            assert abs(got.real - np.real(x)) <= z * se + 1e-12, (ch, k, got, x, se)
            assert abs(got.imag - np.imag(x)) <= z * se + 1e-12, (ch, k, got, x, se)


def test_every_feature_matches_what_was_put_in():
    fs, f, dur, drift, line, sigma = 10_000.0, 97.3, 0.5, 0.02, 0.05 * np.exp(0.7j), 0.01
    feat = record_features(_recording(fs, f, dur, drift=drift, line=line, sigma=sigma))
    assert feat.periods == int((int(fs * dur) - 1) / fs * f)
    assert feat.frequency_hz == pytest.approx(f, abs=1e-4)
    assert feat.start_time_s is None and feat.rig == "ecore_pm" and feat.current_pp_a == 1.4
    _check_harmonics(feat, TRUTH)
    # X_0 is the mean at the middle of the averaged whole periods (the drift included).
    x0 = 0.1 + drift * feat.periods / (2 * feat.frequency_hz)
    assert abs(feat.harmonics["flux_Wb"][0].real - x0) <= 4.5 * feat.se["flux_Wb"][0]
    slope, slope_se = feat.dc_slope["flux_Wb"]
    assert abs(slope - drift) <= 4 * slope_se
    assert slope_se < drift / 5  # the drift is seen, not lost in its SE
    amp, amp_se = feat.lines["flux_Wb"][50.0]
    assert abs(amp.real - line.real) <= 4 * amp_se and abs(amp.imag - line.imag) <= 4 * amp_se
    assert amp_se == pytest.approx(sigma * math.sqrt(2 / (fs * dur)), rel=0.05)
    for other in (60.0, 150.0, 180.0):  # no line there
        a, s = feat.lines["flux_Wb"][other]
        assert abs(a.real) <= 4.5 * s and abs(a.imag) <= 4.5 * s
    assert feat.noise_rms["flux_Wb"] == pytest.approx(sigma, rel=0.03)
    assert feat.noise_rms["current_A"] == pytest.approx(1e-5, rel=0.03)
    # White noise: the SE is the Cramer-Rao bound sigma sqrt(2/N) (not inflated).
    n_avg = feat.periods * fs / feat.frequency_hz
    assert feat.se["flux_Wb"][1] == pytest.approx(sigma * math.sqrt(2 / n_avg), rel=0.03)
    assert feat.se["flux_Wb"][0] == pytest.approx(sigma / math.sqrt(n_avg), rel=0.03)


def test_features_do_not_depend_on_where_the_record_starts():
    a = record_features(_recording(10_000.0, 97.3, 0.3, phase0=0.4, sigma=1e-3))
    b = record_features(_recording(10_000.0, 97.3, 0.3, phase0=2.9, sigma=1e-3, seed=1))
    for k in range(1, 6):
        d = a.harmonics["flux_Wb"][k] - b.harmonics["flux_Wb"][k]
        s = math.hypot(a.se["flux_Wb"][k], b.se["flux_Wb"][k])
        assert abs(d.real) <= 4.5 * s and abs(d.imag) <= 4.5 * s, k


def test_fft_normalisation_and_spline_gain_on_an_analytic_signal():
    """No noise, 12.3 samples a period: the third harmonic sits at 0.24 fs where the cubic spline
    alone would lose 1.6 %; the coefficients must come out exact."""
    fs, f = 1230.0, 100.0
    t = np.arange(1230) / fs
    current = np.cos(2 * np.pi * f * t) + 0.2 * np.cos(3 * 2 * np.pi * f * t - 1.1)
    sense = 0.3 + 1.5 * np.cos(2 * np.pi * f * t - 0.25) + 0.4 * np.sin(3 * 2 * np.pi * f * t)
    rec = Recording(None, fs, {"current_A": current, "sense_V": sense}, {**META, "frequency_Hz": f})
    feat = record_features(rec, harmonics=6)
    h = feat.harmonics["sense_V"]
    assert 1 - spline_gain(2 * np.pi * 0.24) > 0.01  # the correction matters at this harmonic
    np.testing.assert_allclose(h[:4], [0.3, 1.5 * np.exp(-0.25j), 0.0, -0.4j], atol=2e-4)
    np.testing.assert_allclose(feat.harmonics["current_A"][3], 0.2 * np.exp(-1.1j), atol=2e-4)
    assert np.isnan(h[6]) and np.isnan(feat.se["sense_V"][6])  # 600 Hz >= 0.45 fs
    assert abs(h[5]) < 2e-4  # 500 Hz < 0.45 fs: reported


def test_standard_errors_agree_with_a_monte_carlo():
    """The reported SE against the spread of 300 noisy copies; the tolerance is the Monte-Carlo's
    own: the relative SE of a standard deviation pooled over n values is 1/sqrt(2n)."""
    trials, sigma, fs, f = 300, 0.01, 5000.0, 97.3
    ks = np.arange(1, 6)
    re, im, x0, reported = [], [], [], []
    for seed in range(trials):
        feat = record_features(_recording(fs, f, 0.2, seed=seed, sigma=sigma, line=0.02), harmonics=5)
        h = feat.harmonics["flux_Wb"]
        re.append(h[ks].real)
        im.append(h[ks].imag)
        x0.append(h[0].real)
        reported.append(feat.se["flux_Wb"][:6])
    se = np.mean(reported, axis=0)
    dev = np.concatenate([(np.array(re) - np.mean(re, axis=0)) / se[ks], (np.array(im) - np.mean(im, axis=0)) / se[ks]], axis=1)
    ratio = np.sqrt(np.mean(dev ** 2) * trials / (trials - 1))
    assert abs(ratio - 1) <= 4 / math.sqrt(2 * dev.size), ratio
    ratio0 = np.std(x0, ddof=1) / se[0]
    assert abs(ratio0 - 1) <= 4 / math.sqrt(2 * trials), ratio0


def test_coloured_noise_inflates_the_standard_error():
    """Low-pass noise (corner 6 f, like drift and 1/f noise) is dense at the harmonics and thin
    elsewhere: its per-sample rms understates the harmonics' error, the alternating average sees
    that, and the SE grows so that the true harmonics stay within it."""
    fs, f = 10_000.0, 97.3
    t = np.arange(5000) / fs
    coloured = lfilter([1.0], [1.0, -math.exp(-2 * np.pi * 6 * f / fs)], np.random.default_rng(3).standard_normal(t.size))
    white = record_features(_recording(fs, f, 0.5, sigma=1e-3))
    rec = _recording(fs, f, 0.5, sigma=1e-3, extra={"force_N": 0.01 * coloured + np.cos(2 * np.pi * f * t + 0.4)})
    feat = record_features(rec)
    n_avg = feat.periods * fs / feat.frequency_hz
    assert feat.se["force_N"][2] > 1.5 * feat.noise_rms["force_N"] * math.sqrt(2 / n_avg)
    _check_harmonics(feat, {"force_N": {1: 1.0, 2: 0.0, 3: 0.0, 4: 0.0}})
    assert white.se["flux_Wb"][2] == pytest.approx(white.noise_rms["flux_Wb"] * math.sqrt(2 / n_avg), rel=0.01)


def test_short_records_of_two_periods():
    fs, f = 10_000.0, 20.5
    rec = _recording(fs, f, 0.1, sigma=1e-3)
    feat = record_features(rec)
    assert feat.periods == 2 and feat.duration_s == pytest.approx(0.1)
    assert all(math.isnan(v) for v in feat.dc_slope["flux_Wb"])
    _check_harmonics(feat, TRUTH)
    # Harmonics 20.5 Hz apart, resolution 2/duration = 20 Hz: no line can be told from them.
    assert feat.lines["flux_Wb"] == {}


def test_channels_are_those_of_the_recording_and_start_time_is_read():
    rec = _recording(10_000.0, 97.3, 0.2, extra={"force_N": np.zeros(2000) + 3.0})
    rec.metadata["start_time_s"] = 12.5
    feat = record_features(rec)
    assert set(feat.harmonics) == set(feat.se) == set(feat.lines) == {"current_A", "flux_Wb", "force_N"}
    assert feat.start_time_s == 12.5
    assert feat.harmonics["force_N"][0].real == pytest.approx(3.0)


def test_a_recording_without_current_is_refused_by_name():
    fs = 10_000.0
    rec = Recording(None, fs, {"flux_Wb": np.cos(np.arange(2000) / fs * 2 * np.pi * 97.3)},
                    {**META, "frequency_Hz": 97.3})
    with pytest.raises(ValueError, match="ecore_pm recording at 97.3 Hz.*current_A"):
        record_features(rec)


def test_a_recording_of_one_period_is_refused_by_name():
    rec = _recording(10_000.0, 15.0, 0.1)
    with pytest.raises(ValueError, match="ecore_pm recording at 15 Hz"):
        record_features(rec)


def test_simulated_ecore_flux_lags_current():
    """Hysteresis and eddy currents make the flux lag the current (energy goes into the iron)."""
    feat = record_features(simulate_recording("ecore_pm", 120.0, 1.4, 0.2))
    x1, se = feat.harmonics["flux_Wb"][1], feat.se["flux_Wb"][1]
    assert abs(x1) > 100 * se
    assert -x1.imag > 5 * se  # a lag: a negative angle, significant
    assert 0 < -np.angle(x1) < np.pi / 2
    assert set(feat.harmonics) >= {"current_A", "flux_Wb", "force_N"}
