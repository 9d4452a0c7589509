"""The force error of Eq. 5 before and after each correction, against closed forms."""

import numpy as np
import pytest

from hystbench.analysis.force_error import analytical_model, force_error, loop_eye, phase_delay_model
from hystbench.analysis.method import measure_delays
from hystbench.analysis.periodic import synchronous_average
from hystbench.formats.recording import Recording
from hystbench.physics.phase_delay_model import PhaseDelayModel

COEF = (172.0, 68.0, 4.0)


def one_period(n=2000):
    return np.arange(n) / n


def test_eye_of_a_pure_delay_is_2_k1_i_sin_theta():
    amp, theta = 0.7, np.radians(1.5)
    p = one_period()
    model = PhaseDelayModel.non_hysteretic(COEF)
    i = amp * np.sin(2 * np.pi * p)
    err = model.static_force(amp * np.sin(2 * np.pi * p - theta)) - model.static_force(i)
    eye, at = loop_eye(i, err, at=0.0)
    assert eye == pytest.approx(2 * COEF[1] * amp * np.sin(theta), rel=1e-6)


def test_eye_without_magnet_is_k2_i2_sin_2theta_at_i_over_root_2():
    amp, theta, k2 = 0.635, np.radians(2.0), 8.0
    p = one_period(4000)
    i = amp * np.sin(2 * np.pi * p)
    err = k2 * (amp * np.sin(2 * np.pi * p - theta)) ** 2 - k2 * i**2
    eye, at = loop_eye(i, err)
    assert eye == pytest.approx(k2 * amp**2 * np.sin(2 * theta), rel=1e-4)
    assert abs(at) == pytest.approx(amp / np.sqrt(2), rel=0.02)
    assert loop_eye(i, err, at=0.0)[0] < 1e-3 * eye  # the loop closes at i = 0


def synthetic(rig, theta, tau, fs=100_000.0, f_nominal=320.0, seconds=0.2, noise=0.0):
    """Current, flux behind it by theta, force = Eq. 1 of the flux-delayed current, then late by tau."""
    f = f_nominal * (1 + 25e-6)
    t = np.arange(int(seconds * fs)) / fs
    w = 2 * np.pi * f
    amp = 0.7
    model = analytical_model(rig)
    rng = np.random.default_rng(0)
    force = model.static_force(amp * np.sin(w * (t - tau) - theta)) + noise * rng.standard_normal(t.size)
    ch = {"current_A": amp * np.sin(w * t), "flux_Wb": 2e-5 * np.sin(w * t - theta), "force_N": force}
    meta = {"rig": rig, "frequency_Hz": f_nominal, "sample_rate_Hz": fs, "current_pp_A": 2 * amp}
    return Recording(None, fs, ch, meta), model, amp


def test_corrections_of_a_known_hysteresis_and_instrument_delay():
    theta, tau = np.radians(2.0), 11e-6
    rec, eq1, amp = synthetic("ecore_pm", theta, tau)
    d = measure_delays(rec)
    assert d.delays_s["instrument"] == pytest.approx(tau, rel=1e-6)
    assert d.theta_hyst_rad == pytest.approx(theta, rel=1e-6)
    fe = force_error(rec, phase_delay_model("ecore_pm", [d]), d)
    k1 = eq1.k1_n_per_a
    phi_instr = 2 * np.pi * d.frequency_hz * tau
    assert fe.eye_n("before") == pytest.approx(2 * k1 * amp * np.sin(theta + phi_instr), rel=1e-4)
    assert fe.eye_n("instrument") == pytest.approx(2 * k1 * amp * np.sin(theta), rel=1e-4)
    assert fe.max_abs_n("hysteresis") < 1e-6 * fe.force_range_n  # Eq. 6 is the truth here
    assert fe.accuracy_pct("hysteresis") > 99.9999
    s = fe.summary()
    assert s["periods_averaged"] == 63 and s["accuracy_pct"]["instrument"] < s["accuracy_pct"]["hysteresis"]


def test_synchronous_average_uses_the_true_frequency_and_removes_noise():
    rec, _, _ = synthetic("ecore_pm", 0.0, 0.0, seconds=1.0, noise=0.5)
    d = measure_delays(rec)
    avg = synchronous_average(rec, d.frequency_hz, 500)
    truth = analytical_model("ecore_pm").static_force(0.7 * np.sin(2 * np.pi * avg.phase))
    assert avg.periods == 320
    assert np.max(np.abs(avg.channels["force_N"] - truth)) < 5 * 0.5 / np.sqrt(avg.periods)
    assert avg.noise_rms["force_N"] == pytest.approx(0.5, rel=0.1)
    # averaged at the nominal 320 Hz instead, the 25 ppm drift would smear the loop
    nominal = synchronous_average(rec, 320.0, 500)
    assert np.max(np.abs(nominal.channels["force_N"] - truth)) > 3 * np.max(np.abs(avg.channels["force_N"] - truth))


def test_phase_delay_model_closes_the_loops_of_the_simulated_rig():
    from hystbench.reports.paper import simulate_ecore

    recs = simulate_ecore("ecore_pm", [(160.0, 1.4), (320.0, 1.4)], duration_s=0.1)
    ds = [measure_delays(r) for r in recs]
    model = phase_delay_model("ecore_pm", ds)
    fe = force_error(recs[1], model, ds[1])
    assert fe.eye_n("hysteresis") < 0.2 * fe.eye_n("instrument") < 0.2 * fe.eye_n("before")
    assert fe.max_abs_ac_n("hysteresis") < fe.max_abs_ac_n("instrument")
