"""The independent bench against expectations computed independently of its own code paths:
closed forms, virtual work, hand-built transfer functions, the paper's magnitudes."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import signal

from independent_bench import BASELINE, simulate_recording
from independent_bench import magnetics as mag
from independent_bench.bench import BenchConstants, DEFAULTS

QUIET = {"static_hysteresis": True, "lamination_eddy_currents": True, "instrument_filter": True}


def phase_deg(x: np.ndarray, t: np.ndarray, f: float) -> float:
    """Phase of x's component at f (deg), by least squares with an offset and a slope."""
    a = np.column_stack([np.cos(2 * np.pi * f * t), np.sin(2 * np.pi * f * t), np.ones_like(t), t])
    c = np.linalg.lstsq(a, x, rcond=None)[0]
    return math.degrees(math.atan2(-c[1], c[0]))


def lag_deg(cols: dict, early: str, late: str, f: float) -> float:
    """How far ``late`` lags ``early`` at f (deg), wrapped to (-180, 180]."""
    t = cols["time_s"]
    d = phase_deg(cols[early], t, f) - phase_deg(cols[late], t, f)
    return (d + 180) % 360 - 180


def test_cauer_ladder_approaches_the_slab_tanh_law():
    w = 2 * np.pi * np.array([40.0, 480.0, 3000.0, 20000.0])
    mu, sigma, d = 600 * mag.MU0, 2e6, 0.35e-3
    exact = mag.slab_reluctivity_factor(w, mu, sigma, d)
    coarse = mag.ladder_reluctivity_factor(w, mu, sigma, d, 4)
    fine = mag.ladder_reluctivity_factor(w, mu, sigma, d, 64)
    assert np.max(np.abs(fine / exact - 1)) < 1e-3
    assert np.max(np.abs(fine - exact)) < np.max(np.abs(coarse - exact))  # converges with layers
    # low frequency: the classical eddy term, nu_s/nu = 1 + j w sigma mu d^2 / 12
    small = mag.ladder_reluctivity_factor(np.array([2 * np.pi * 5.0]), mu, sigma, d, 64)[0]
    assert small.imag == pytest.approx(2 * np.pi * 5.0 * sigma * mu * d * d / 12, rel=1e-2)


@pytest.mark.parametrize("magnet, knee", [(False, None), (True, None), (True, 1.05)])
def test_gap_force_equals_virtual_work_on_the_coenergy_map(magnet, knee):
    geo = mag.ECoreGeometry()
    mmf = geo.turns * 0.6 + (mag.magnet_mmf(geo) if magnet else 0.0)
    phi = mag.static_flux_outer(geo, np.array([mmf]), geo.gap_m, magnet, knee)
    direct = float(mag.gap_force(geo, phi, geo.gap_m, magnet)[0])
    assert mag.coenergy_force(geo, mmf, geo.gap_m, magnet, knee) == pytest.approx(direct, rel=2e-4)


def test_bouc_wen_loop_is_closed_and_lossy():
    b = 0.12 * np.sin(2 * np.pi * np.arange(512) / 512)
    p = DEFAULTS["static_hysteresis"]
    h = mag.periodic_bouc_wen(b, p["a_A_per_m_per_T"], p["beta_per_T"], p["gamma_per_T"])
    again = mag.periodic_bouc_wen(b, p["a_A_per_m_per_T"], p["beta_per_T"], p["gamma_per_T"])
    np.testing.assert_allclose(h, again)
    area = float(np.sum(h * np.gradient(np.unwrap(b))))  # \oint h dB > 0: energy lost per cycle
    assert area > 0
    assert np.max(np.abs(h)) <= p["a_A_per_m_per_T"] / (p["beta_per_T"] + p["gamma_per_T"]) + 1e-9


def test_instrument_phase_at_320hz_is_the_hand_built_transfer_function():
    fi = DEFAULTS["instrument_filter"]
    wn, w0 = 2 * np.pi * fi["fn_Hz"], 2 * np.pi * fi["lpf_Hz"]
    b = np.polymul([wn**2], [w0**2])
    a = np.polymul([1, 2 * fi["zeta"] * wn, wn**2], [1, 2 * fi["lpf_zeta"] * w0, w0**2])
    bench = BenchConstants()
    f_true = 320.0 * (1 + bench.generator_clock_ppm * 1e-6)
    _, h = signal.freqs(b, a, worN=[2 * np.pi * f_true])
    expected = -math.degrees(np.angle(h[0]))
    cols, _ = simulate_recording("voicecoil_ferrite", 320.0, 1.0, effects={"instrument_filter": True}, seed=0)
    # the ADC clock is a few ppm fast: fit at the frequency the samples show
    f_seen = f_true / (1 + bench.adc_clock_ppm * 1e-6)
    assert lag_deg(cols, "current_A", "force_N", f_seen) == pytest.approx(expected, abs=0.01)
    assert 1.0 < expected < 1.6  # the paper's ~1.5 deg


def test_magnitudes_are_the_papers():
    pm, _ = simulate_recording("ecore_pm", 160.0, 1.4, effects=BASELINE, seed=1)
    assert 115 < pm["force_N"].min() < 135 and 210 < pm["force_N"].max() < 230
    ec, _ = simulate_recording("ecore", 160.0, 1.27, effects=BASELINE, seed=1)
    assert -0.2 < ec["force_N"].min() < 0.2 and 2.8 < ec["force_N"].max() < 3.6


def test_delays_at_320hz_instrument_and_hysteresis_of_the_same_order():
    cols, _ = simulate_recording("ecore_pm", 320.0, 1.4, effects=QUIET, seed=2)
    f = 320.0 * (1 - 4.7e-6 - 3.1e-6)
    hyst = lag_deg(cols, "current_A", "flux_Wb", f)
    instr = lag_deg(cols, "flux_Wb", "force_N", f)
    assert 0.3 < hyst < 3.0 and 1.0 < instr < 1.6
    assert 1.5 < hyst + instr < 5.0  # force lags current by a few degrees


def test_same_seed_same_recording_and_noise_follows_the_seed():
    a, sa = simulate_recording("ecore", 80.0, 1.27, effects=BASELINE, seed=5, start_time_s=10.0)
    b, _ = simulate_recording("ecore", 80.0, 1.27, effects=BASELINE, seed=5, start_time_s=10.0)
    c, _ = simulate_recording("ecore", 80.0, 1.27, effects=BASELINE, seed=6, start_time_s=10.0)
    for k in a:
        np.testing.assert_array_equal(a[k], b[k])
    assert not np.array_equal(a["force_N"], c["force_N"])
    assert set(a) == {"time_s", "current_A", "force_N", "flux_Wb", "command_V"}
    assert a["time_s"].size == round(48 * 100e3 / 80.0)
    assert sa == {"rig": "ecore", "frequency_Hz": 80.0, "sample_rate_Hz": 100e3, "current_pp_A": 1.27,
                  "start_time_s": 10.0, "sense_turns": 10}


def test_unknown_effects_and_parameters_are_refused():
    with pytest.raises(ValueError, match="unknown effect"):
        simulate_recording("ecore", 80.0, 1.27, effects={"gremlins": True}, seed=0)
    with pytest.raises(ValueError, match="unknown parameters"):
        simulate_recording("ecore", 80.0, 1.27, effects={"integrator_leak": {"tau": 1}}, seed=0)


def test_elliptic_iron_makes_elliptic_loops_whose_lag_grows_with_the_flux_density():
    """The elliptic variant of the iron (issue 29's family): a sine current gives a sine flux (the loop
    is an ellipse: no harmonics), lagging the current by less than the loss angle (the gaps take most
    of the MMF), and more at a larger amplitude (Rayleigh's loss growth)."""
    ell = {"static_hysteresis": {"tan_delta": 0.15, "tan_delta_per_T": 0.5}}
    lags, thd = [], []
    for ipp in (0.3, 1.5):
        cols, _ = simulate_recording("ecore", 40.0, ipp, effects=ell, seed=3, periods=8)
        t, phi = cols["time_s"], cols["flux_Wb"]
        f = 40.0 * (1 + BenchConstants().generator_clock_ppm * 1e-6)
        spec = np.abs(np.fft.rfft(phi - phi.mean()))
        k = int(round(f * t.size / 100e3 * (1 - BenchConstants().adc_clock_ppm * 1e-6)))
        thd.append(max(spec[h * k - 1: h * k + 2].max() for h in range(2, 8)) / spec[k - 1: k + 2].max())
        lags.append(lag_deg(cols, "current_A", "flux_Wb", f))
    assert max(thd) < 1e-4
    assert 0 < lags[0] < lags[1] < math.degrees(math.atan(0.15 + 0.5 * 1.0))
