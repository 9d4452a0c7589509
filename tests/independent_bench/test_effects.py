"""Each effect, switched on alone over a quiet baseline, changes the channels its physics reaches
and no other; where a closed form exists, by the amount it says."""

from __future__ import annotations

import math

import numpy as np
import pytest

from independent_bench import EFFECT_NAMES, simulate_recording
from independent_bench.bench import DEFAULTS, BenchConstants

QUIET = {"static_hysteresis": True, "lamination_eddy_currents": True, "instrument_filter": True}
ALL = {"current_A", "force_N", "flux_Wb", "command_V"}
B = BenchConstants()

# effect -> (rig, frequency, current, start on the day's clock, channels it must change)
CASES = {
    "static_hysteresis": ("ecore_pm", 320.0, 1.4, 0.0, {"force_N", "flux_Wb"}),
    "lamination_eddy_currents": ("ecore_pm", 320.0, 1.4, 0.0, {"force_N", "flux_Wb"}),
    "magnet_eddy_currents": ("ecore_pm", 320.0, 1.4, 0.0, {"force_N", "flux_Wb"}),
    "iron_saturation": ("ecore_pm", 320.0, 1.4, 0.0, {"force_N", "flux_Wb"}),
    "instrument_filter": ("ecore_pm", 320.0, 1.4, 0.0, {"force_N"}),
    "frame_resonance": ("ecore_pm", 320.0, 1.4, 0.0, {"force_N"}),
    "charge_amp_highpass": ("ecore_pm", 40.0, 1.4, 0.0, {"force_N"}),
    "integrator_leak": ("ecore_pm", 40.0, 1.4, 0.0, {"flux_Wb"}),
    "channel_skew": ("ecore_pm", 320.0, 1.4, 0.0, {"current_A"}),
    "force_offset_drift": ("ecore_pm", 320.0, 1.4, 900.0, {"force_N"}),
    "magnet_thermal_drift": ("ecore_pm", 320.0, 1.4, 900.0, {"force_N"}),
    "load_cell_compliance": ("ecore_pm", 320.0, 1.4, 0.0, {"force_N", "flux_Wb"}),
    "mains_pickup": ("ecore_pm", 320.0, 1.4, 0.0, {"force_N", "flux_Wb", "current_A"}),
    "amplifier_distortion": ("ecore_pm", 320.0, 1.4, 0.0, {"force_N", "flux_Wb", "current_A"}),
    "sensor_noise": ("ecore_pm", 320.0, 1.4, 0.0, ALL),
    "adc_quantisation": ("ecore_pm", 320.0, 1.4, 0.0, ALL),
    "excess_loss": ("ecore_pm", 320.0, 1.4, 0.0, {"force_N", "flux_Wb"}),
    "magnetic_relaxation": ("ecore_pm", 320.0, 1.4, 0.0, {"force_N", "flux_Wb"}),
    "iron_thermal_drift": ("ecore", 40.0, 1.27, 900.0, {"force_N", "flux_Wb"}),
}


def test_every_catalogue_name_has_a_case():
    assert set(CASES) == set(EFFECT_NAMES) == set(DEFAULTS)


def _pair(name: str, params: object = True) -> tuple[dict, dict]:
    rig, f, i, start, _ = CASES[name]
    base = {k: v for k, v in QUIET.items() if k != name}
    off, _ = simulate_recording(rig, f, i, effects=base, seed=3, start_time_s=start)
    on, _ = simulate_recording(rig, f, i, effects={**base, name: params}, seed=3, start_time_s=start)
    return off, on


@pytest.mark.parametrize("name", EFFECT_NAMES)
def test_an_effect_changes_its_channels_and_no_other(name):
    off, on = _pair(name)
    changed = {k for k in ALL if k in off and not np.allclose(on[k], off[k], rtol=0, atol=1e-9 * np.ptp(off[k]))}
    assert changed == CASES[name][4]
    np.testing.assert_array_equal(on["time_s"], off["time_s"])


def _f_seen(f: float) -> float:
    return f * (1 + B.generator_clock_ppm * 1e-6) / (1 + B.adc_clock_ppm * 1e-6)


def _phase(x: np.ndarray, t: np.ndarray, f: float) -> float:
    a = np.column_stack([np.cos(2 * np.pi * f * t), np.sin(2 * np.pi * f * t), np.ones_like(t), t])
    c = np.linalg.lstsq(a, x, rcond=None)[0]
    return math.atan2(-c[1], c[0])


def test_integrator_leak_leads_the_flux_as_its_circuit_says():
    off, on = _pair("integrator_leak")
    p = DEFAULTS["integrator_leak"]
    w = 2 * np.pi * 40.0 * (1 + B.generator_clock_ppm * 1e-6)  # the true excitation
    # corner of the real integrator: its feedback resistor and the op-amp's finite gain
    w_leak = 1 / (p["r_feedback_ohm"] * B.integrator_c_f) + 1 / (p["dc_gain"] * B.integrator_r_in_ohm * B.integrator_c_f)
    lead = _phase(on["flux_Wb"], on["time_s"], _f_seen(40.0)) - _phase(off["flux_Wb"], off["time_s"], _f_seen(40.0))
    assert math.degrees(lead) == pytest.approx(math.degrees(math.atan(w_leak / w)), rel=0.02)


def test_charge_amp_highpass_leads_the_force_by_its_time_constant():
    off, on = _pair("charge_amp_highpass")
    tau = DEFAULTS["charge_amp_highpass"]["tau_s"]
    w = 2 * np.pi * 40.0
    lead = _phase(on["force_N"], on["time_s"], _f_seen(40.0)) - _phase(off["force_N"], off["time_s"], _f_seen(40.0))
    assert math.degrees(lead) == pytest.approx(math.degrees(math.atan(1 / (w * tau))), rel=0.02)
    assert on["force_N"][-1000:].mean() < off["force_N"][-1000:].mean()  # the mean decays since the reset


def test_channel_skew_delays_the_current_by_its_time():
    off, on = _pair("channel_skew")
    f = _f_seen(320.0)
    lag = _phase(off["current_A"], off["time_s"], f) - _phase(on["current_A"], on["time_s"], f)
    assert lag == pytest.approx(2 * np.pi * 320.0 * DEFAULTS["channel_skew"]["current_A"], rel=1e-3)


def test_magnet_thermal_drift_grows_along_the_day_and_spares_the_magnetless_rig():
    late = {**QUIET, "magnet_thermal_drift": True}
    early, _ = simulate_recording("ecore_pm", 320.0, 1.4, effects=late, seed=1, start_time_s=0.0)
    later, _ = simulate_recording("ecore_pm", 320.0, 1.4, effects=late, seed=1, start_time_s=3000.0)
    assert later["force_N"].mean() < early["force_N"].mean() - 1.0
    a, _ = simulate_recording("ecore", 320.0, 1.27, effects=QUIET, seed=1, start_time_s=3000.0)
    b, _ = simulate_recording("ecore", 320.0, 1.27, effects=late, seed=1, start_time_s=3000.0)
    np.testing.assert_array_equal(a["force_N"], b["force_N"])


def test_iron_saturation_depends_on_amplitude():
    """Its own knee: harmonics grow faster than the drive (amplitude-dependent distortion)."""
    def third(cur: float, eff: dict) -> float:
        c, _ = simulate_recording("ecore_pm", 160.0, cur, effects=eff, seed=1, periods=8)
        spec = np.abs(np.fft.rfft(c["flux_Wb"]))
        k = int(round(8 * 160.0 * c["time_s"].size / 100e3 / 8 * 8 / 8))
        return float(spec[3 * 8] / spec[8])
    sat = {"iron_saturation": True}  # alone: the Bouc-Wen loop has harmonics of its own
    assert third(1.4, sat) > 3 * third(0.7, sat)
    assert third(1.4, sat) > 100 * third(1.4, {})


def test_frame_resonance_shows_near_its_frequency_on_the_voice_coil():
    eff = {"instrument_filter": True}
    f0 = DEFAULTS["frame_resonance"]["frequency_Hz"]
    off, _ = simulate_recording("voicecoil_ferrite", f0, 1.0, effects=eff, seed=0, periods=24)
    on, _ = simulate_recording("voicecoil_ferrite", f0, 1.0, effects={**eff, "frame_resonance": True}, seed=0, periods=24)
    f = _f_seen(f0)
    dphi = abs(math.degrees(_phase(on["force_N"], on["time_s"], f) - _phase(off["force_N"], off["time_s"], f)))
    assert 0.5 < dphi < 15  # a small mode, as the paper's Fig. 7c shows
