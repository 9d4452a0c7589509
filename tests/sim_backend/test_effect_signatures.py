"""Every effect of the catalogue does what its one line says: each test switches one effect and
checks its signature against a closed form (not against the simulator's own output)."""

import numpy as np
import pytest

from hystbench.analysis.estimation import sine_fit
from hystbench.config import load_rig
from hystbench.physics import presets
from hystbench.sim_backend.measurement import FractionalDelay
from hystbench.sim_backend.rig import SimulatedRig

QUIET = {"sensor_noise": False, "adc_quantisation": False}


def run(rig="ecore_pm", f=320.0, seconds=0.1, ipp=None, **effects):
    r = SimulatedRig(rig, frequency_hz=f, current_pp_a=ipp, effects={**QUIET, **effects}, seed=5)
    return r, r.record(seconds)


def phasor(x, t, f, k=1):
    """Complex amplitude of harmonic k at the known frequency f: a linear least-squares fit of DC
    and the first harmonics (the estimator of tests/analysis/test_estimation.py, validated
    against the Cramer-Rao bound), at the generator's true frequency."""
    fit = sine_fit(x, 1.0 / (t[1] - t[0]), f, harmonics=(1, 2, 3), fit_freq=False)
    c = fit.component(k)
    return c.amplitude * np.exp(1j * c.phase_rad)


def lag_deg(a, b, t, f, k=1):
    return (np.degrees(np.angle(phasor(a, t, f, k)) - np.angle(phasor(b, t, f, k))) + 180) % 360 - 180


def test_lamination_eddy_currents_make_the_lag_grow_with_frequency():
    def spread(**e):
        lags = []
        for f in (40.0, 480.0):
            r, b = run("ecore", f, **e)
            lags.append(lag_deg(b.channels["current_A"], b.channels["flux_Wb"], b.time_s(), r.generator_frequency_hz))
        return lags[1] - lags[0]
    assert spread() > 0.3
    assert abs(spread(lamination_eddy_currents=False)) < 0.05  # hysteresis alone is rate-independent


def test_magnet_eddy_currents_add_lag_only_with_a_magnet():
    def lag(rig, **e):
        r, b = run(rig, 480.0, **e)
        return lag_deg(b.channels["current_A"], b.channels["flux_Wb"], b.time_s(), r.generator_frequency_hz)
    assert lag("ecore_pm") - lag("ecore_pm", magnet_eddy_currents=False) > 0.05
    assert lag("ecore", magnet_eddy_currents=True) == pytest.approx(lag("ecore"), abs=1e-9)


def test_iron_saturation_compresses_the_force_at_high_current():
    # Far beyond the operating point (30 A-pp: the linear circuit would ask for ~2.9 T) the
    # saturating iron takes MMF from the gaps and B levels off near the material's ~2 T.
    _, sat = run("ecore", 40.0, seconds=0.06, ipp=30.0, static_hysteresis=False)
    _, lin = run("ecore", 40.0, seconds=0.06, ipp=30.0, static_hysteresis=False, iron_saturation=False)
    assert sat.channels["force_N"].max() < 0.6 * lin.channels["force_N"].max()
    b_peak = np.max(np.abs(sat.channels["flux_Wb"])) / (10e-3 * 20e-3)  # outer tooth area
    assert 1.7 < b_peak < 2.3


def test_saturation_far_beyond_the_material_is_refused_not_invented():
    from hystbench.errors import SimulationError

    with pytest.raises(SimulationError, match="saturation"):
        run("ecore", 40.0, seconds=0.02, ipp=400.0)


def test_frame_resonance_shifts_the_320_hz_phase_by_its_closed_form():
    r, on = run("voicecoil_ferrite", frame_resonance=True)
    _, off = run("voicecoil_ferrite", frame_resonance=False)
    f, t = r.generator_frequency_hz, on.time_s()
    zeta = 0.02
    expected = sum(np.degrees(np.arctan(2 * zeta * 1.2 * (f / fm) / (1 - (f / fm) ** 2))
                              - np.arctan(2 * zeta * (f / fm) / (1 - (f / fm) ** 2))) for fm in (850.0, 1175.0))
    shift = lag_deg(on.channels["current_A"], on.channels["force_N"], t, f) - lag_deg(
        off.channels["current_A"], off.channels["force_N"], t, f)
    assert -shift == pytest.approx(expected, abs=0.01)  # a lead: less lag


def test_charge_amp_highpass_leads_by_atan_1_over_w_tau():
    tau, f = 0.05, 40.0
    r, on = run("voicecoil_ferrite", f, seconds=1.0, charge_amp_highpass={"time_constant_s": tau},
                instrument_filter=False)
    fg = r.generator_frequency_hz
    lead = -lag_deg(on.channels["current_A"], on.channels["force_N"], on.time_s(), fg)
    assert lead == pytest.approx(np.degrees(np.arctan(1 / (2 * np.pi * fg * tau))), abs=0.05)


def test_integrator_leak_leads_the_flux_by_atan_1_over_w_tau():
    tau, f = 0.05, 40.0
    r, on = run("ecore", f, seconds=1.0, integrator_leak={"time_constant_s": tau})
    _, off = run("ecore", f, seconds=1.0)
    fg, t = r.generator_frequency_hz, on.time_s()
    lead = lag_deg(off.channels["current_A"], off.channels["flux_Wb"], t, fg) - lag_deg(
        on.channels["current_A"], on.channels["flux_Wb"], t, fg)
    assert lead == pytest.approx(np.degrees(np.arctan(1 / (2 * np.pi * fg * tau))), abs=0.05)


def test_channel_skew_delays_a_channel_by_its_seconds():
    skew = 7.3e-6
    r, on = run("ecore_pm", channel_skew={"force_N": skew, "flux_Wb": 0.0})
    _, off = run("ecore_pm")
    f, t = r.generator_frequency_hz, on.time_s()
    extra = lag_deg(off.channels["force_N"], on.channels["force_N"], t, f)
    assert extra == pytest.approx(360 * f * skew, rel=1e-3)


@pytest.mark.parametrize("skew_s", [0.5e-6, 1e-6, 13.7e-6])
def test_a_skew_delays_every_frequency_and_keeps_its_amplitude(skew_s):
    """A late sample clock moves a tone, it does not shrink it: up to the voice coil's 3 kHz a skewed
    sine keeps its amplitude to 1e-9 and lags by 360 f skew within 0.5 %.  (Linear interpolation, the
    delay before, lost p(1 - p)(wT)^2/2 of the amplitude: 8e-4 at 3 kHz for 0.5 us.)  The samples do
    not depend on how the stream is cut."""
    fs = 100e3
    t = np.arange(20_000) / fs
    for f in (40.0, 1000.0, 3000.0):
        x = np.sin(2 * np.pi * f * t + 0.3)
        y = FractionalDelay(skew_s * fs)(x)
        d = FractionalDelay(skew_s * fs)
        cut = np.concatenate([d(part) for part in np.split(x, [1, 777, 5000])])
        assert np.max(np.abs(cut - y)) <= 1e-12
        settled = slice(4000, None)  # past the allpass's start (its pole: 0.905^n for 0.5 us)
        a, b = phasor(x[settled], t[settled], f), phasor(y[settled], t[settled], f)
        assert abs(b) / abs(a) == pytest.approx(1.0, abs=1e-9)
        assert np.degrees(np.angle(a / b)) == pytest.approx(360 * f * skew_s, rel=5e-3)


def test_force_offset_drift_adds_offset_plus_rate_times_time():
    _, on = run("ecore_pm", seconds=0.2, force_offset_drift={"offset_n": 0.5, "drift_n_per_s": 2.0})
    _, off = run("ecore_pm", seconds=0.2)
    d = on.channels["force_N"] - off.channels["force_N"]
    np.testing.assert_allclose(d, 0.5 + 2.0 * on.time_s(), atol=1e-9)


def test_magnet_thermal_drift_lowers_the_bias_force_as_remanence_squared():
    rate, tc, seconds = 5.0, -0.0012, 0.2  # 1 K over the record
    _, on = run("ecore_pm", 320.0, seconds=seconds, magnet_thermal_drift={"kelvin_per_s": rate},
                instrument_filter=False)
    t, force = on.time_s(), on.channels["force_N"]
    n = int(round(100_000 / 320)) * 10
    early, late = force[:n].mean(), force[-n:].mean()
    dt = t[-n:].mean() - t[:n].mean()
    # F0 ~ Fm^2 dominates the mean: d ln F / dt ~ 2 tc rate (the coil term averages out)
    assert (late - early) / early == pytest.approx(2 * tc * rate * dt, rel=0.1)


def test_load_cell_compliance_closes_the_gap_by_f_over_k():
    k = 2e8
    _, on = run("ecore_pm", seconds=0.05, load_cell_compliance={"stiffness_n_per_m": k}, instrument_filter=False)
    _, off = run("ecore_pm", seconds=0.05, instrument_filter=False)
    mec = presets.ecore_mec(load_rig("ecore_pm"))
    z, h = mec.geometry.airgap_m, 1e-8
    f0 = off.channels["force_N"]
    # F(z - F/k) ~ F - dF/dz F / k, with dF/dz at the bias point (current ~0)
    dfdz = (mec.force(0.0, z + h) - mec.force(0.0, z - h)) / (2 * h)
    i = on.channels["current_A"]
    near_zero = np.abs(i) < 0.02
    expected = -dfdz * f0[near_zero] / k
    np.testing.assert_allclose((on.channels["force_N"] - f0)[near_zero], expected, rtol=0.1)


def test_mains_pickup_puts_50_hz_on_the_sense_coil():
    r, on = run("ecore_pm", seconds=0.2, mains_pickup={"sense_v": 1e-3})
    _, off = run("ecore_pm", seconds=0.2)
    d, t = on.channels["sense_V"] - off.channels["sense_V"], on.time_s()
    assert abs(phasor(d, t, 50.0)) == pytest.approx(1e-3, rel=1e-3)
    assert abs(phasor(d, t, 50.0, 3)) == pytest.approx(0.3e-3, rel=1e-3)


def test_amplifier_distortion_adds_the_second_harmonic_of_k2_i_squared():
    k2 = 0.01
    r, on = run("ecore_pm", seconds=0.1, amplifier_distortion={"second": k2, "third": 0.0})
    f, t = r.generator_frequency_hz, on.time_s()
    amp = 0.7
    # k2 (A sin)^2 = k2 A^2 / 2 (1 - cos 2wt): second harmonic of amplitude k2 A^2 / 2
    assert abs(phasor(on.channels["current_A"], t, f, 2)) == pytest.approx(k2 * amp**2 / 2, rel=1e-3)
