"""The measurement method on the simulated rig, against delays known in closed form."""

import numpy as np
import pytest

from hystbench.analysis.estimation import phase_delay
from hystbench.analysis.method import HARMONICS, covariance_delays, estimate, measure_delays
from hystbench.formats.recording import Recording
from hystbench.physics import presets
from hystbench.config import load_rig
from hystbench.sim_backend.rig import SimulatedRig

#: every lag of the actuator off: linear iron, no eddy currents (the instrument filter stays on)
NO_LAG = {"static_hysteresis": False, "iron_saturation": False, "lamination_eddy_currents": False,
          "magnet_eddy_currents": False}


def simulate(rig, f, ipp=None, seconds=0.1, effects=None, seed=1):
    sim = SimulatedRig(rig, frequency_hz=f, current_pp_a=ipp, effects=effects, seed=seed)
    block = sim.record(seconds)
    return Recording(None, sim.fs_hz, dict(block.channels), sim.metadata())


@pytest.mark.parametrize("rig,k", [("ecore_pm", 1), ("ecore", 2)])
def test_instrument_delay_is_the_instrument_models_at_the_force_frequency(rig, k):
    f = 320.0
    d = measure_delays(simulate(rig, f, effects=NO_LAG))
    model = presets.instrument(load_rig(rig))
    expected = float(model.delay_s(k * f))  # with magnet at f; without, the force is at 2f
    tol = max(4 * d.delays_std_s["instrument"], 2e-3 * expected)
    assert d.harmonic == k
    assert d.delays_s["instrument"] == pytest.approx(expected, abs=tol)
    assert d.delays_s["total"] == pytest.approx(expected, abs=tol)
    assert abs(d.delays_s["hysteresis"]) < max(4 * d.delays_std_s["hysteresis"], 2e-9)
    assert d.frequency_hz == pytest.approx(f * (1 + 25e-6), abs=5 * d.frequency_std_hz)  # generator clock


@pytest.mark.parametrize("rig", ["ecore_pm", "ecore"])
def test_injected_channel_delays_come_out_exactly(rig):
    # channel skew delays each ADC channel by a known time: the truth in closed form
    skew = {"current_A": 1e-6, "flux_Wb": 6e-6, "force_N": 16e-6, "sense_V": 0.0, "command_V": 0.0}
    effects = {**NO_LAG, "instrument_filter": False, "channel_skew": skew}
    d = measure_delays(simulate(rig, 160.0, effects=effects))
    for name, want in (("hysteresis", 5e-6), ("instrument", 10e-6), ("total", 15e-6)):
        assert d.delays_s[name] == pytest.approx(want, abs=max(4 * d.delays_std_s[name], 5e-9)), name


def test_delays_add_up_and_eddy_currents_lag_the_flux():
    d = measure_delays(simulate("ecore_pm", 320.0, effects={"static_hysteresis": False, "iron_saturation": False}))
    assert d.delays_s["hysteresis"] > 20 * d.delays_std_s["hysteresis"]
    assert d.delays_s["total"] == pytest.approx(d.delays_s["hysteresis"] + d.delays_s["instrument"], rel=0.02)
    assert d.phase_deg("hysteresis") == pytest.approx(np.degrees(d.theta_hyst_rad))


@pytest.mark.parametrize("effects", [None, {"static_hysteresis": False}, {"iron_saturation": False}])
def test_with_magnet_every_delay_is_read_at_one_frequency_so_they_add_up(effects):
    # each channel is fitted once, at the frequency its current and flux found: total is the sum
    d = measure_delays(simulate("ecore_pm", 320.0, effects=effects))
    assert d.delays_s["total"] == pytest.approx(d.delays_s["hysteresis"] + d.delays_s["instrument"], rel=1e-9)


@pytest.mark.parametrize("rig,f", [("ecore_pm", 160.0), ("ecore_pm", 40.0), ("ecore", 160.0), ("ecore", 480.0)])
def test_delays_read_off_one_fit_per_channel_agree_with_fitting_each_pair_on_its_own(rig, f):
    # the independent way: each pair (its drive and the force) fitted jointly with a frequency of
    # its own, as the method did before it read every delay off one fit per channel
    rec = simulate(rig, f, seconds=0.2)
    d = measure_delays(rec)
    i, phi, force = (rec.channels[c] for c in ("current_A", "flux_Wb", "force_N"))
    if d.harmonic == 2:
        i, phi = (i - i.mean()) ** 2, (phi - phi.mean()) ** 2
    for name, ref in (("instrument", phi), ("total", i)):
        pair = phase_delay(ref, force, rec.fs_hz, d.frequency_hz, harmonic=d.harmonic, harmonics=HARMONICS)
        assert d.delays_s[name] == pytest.approx(float(pair.delay_s), abs=0.1 * float(pair.delay_se_s)), name
        assert d.delays_std_s[name] == pytest.approx(float(pair.delay_se_s), rel=0.05), name


def test_covariance_method_agrees_to_one_sample():
    rec = simulate("ecore_pm", 320.0, effects={"static_hysteresis": False, "iron_saturation": False})
    d = measure_delays(rec)
    cov = covariance_delays(rec, d.frequency_hz)
    for name in ("hysteresis", "instrument", "total"):
        assert abs(cov[name] - d.delays_s[name]) <= 1.0 / rec.fs_hz


def test_estimate_reports_delays_phases_and_the_papers_method():
    rec = simulate("ecore_pm", 320.0, effects={"static_hysteresis": False, "iron_saturation": False})
    out = estimate(rec)
    assert set(out["delays_s"]) == set(out["delays_std_s"]) == {"hysteresis", "instrument", "total"}
    assert out["frequency_Hz"] == pytest.approx(320.008, abs=1e-3)
    assert out["phases_deg"]["instrument"] == pytest.approx(1.28, abs=0.05)
    assert out["covariance_method"]["resolution_s"] == 1e-5
    assert out["instrument_model"]["phase_deg"] == pytest.approx(1.282, abs=0.01)
