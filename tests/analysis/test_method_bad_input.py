"""Bad input to the method: an EstimationError naming the recording and the reason, never a number."""

import numpy as np
import pytest

from hystbench.analysis.method import measure_delays
from hystbench.formats.recording import Recording
from hystbench.errors import EstimationError
from hystbench.sim_backend.rig import SimulatedRig

FAST = {"static_hysteresis": False, "iron_saturation": False}


def simulate(rig="ecore_pm", f=320.0, seconds=0.05, **kw):
    sim = SimulatedRig(rig, frequency_hz=f, effects=FAST if rig.startswith("ecore") else None, seed=3, **kw)
    block = sim.record(seconds)
    return Recording("bench/run_0042", sim.fs_hz, dict(block.channels), sim.metadata())


def refused(rec, *words):
    with pytest.raises(EstimationError) as err:
        measure_delays(rec)
    msg = str(err.value)
    assert "run_0042" in msg, msg
    for w in words:
        assert w in msg, msg
    return msg


def test_shorter_than_two_periods():
    refused(simulate(f=40.0, seconds=0.04), "1.60 periods", "at least two")


def test_clipped_channel():
    rec = simulate()
    f = rec.channels["force_N"]
    rec.channels["force_N"] = np.minimum(f, f.min() + 0.9 * np.ptp(f))
    refused(rec, "'force_N'", "clipped")


def test_clipped_flag_in_the_sidecar():
    rec = simulate()
    rec.metadata["clipped"] = True
    refused(rec, "clipped")


def test_flat_channel():
    rec = simulate()
    rec.channels["flux_Wb"] = np.zeros(rec.n)
    refused(rec, "'flux_Wb'", "flat")


def test_nan_sample():
    rec = simulate()
    rec.channels["current_A"][17] = np.nan
    refused(rec, "'current_A'", "NaN", "sample 17")


def test_missing_channel():
    rec = simulate()
    del rec.channels["flux_Wb"], rec.channels["sense_V"]  # a sense voltage alone would be integrated
    refused(rec, "'flux_Wb'", "needs", "or sense_V, with the sidecar's sense_turns")


def test_frequency_not_in_the_data():
    rec = simulate(f=100.0)
    rec.metadata["frequency_Hz"] = 320.0  # the sidecar says 320 Hz, the signal is at 100 Hz
    msg = refused(rec, "320 Hz", "frequency_Hz")
    assert "peaks at 100" in msg


def test_fitted_frequency_far_from_the_nominal():
    rec = simulate(f=320.0, seconds=0.2)
    rec.metadata["frequency_Hz"] = 319.0  # 3000 ppm off: within a DFT bin, but not a clock error
    refused(rec, "ppm", "319")


def test_voice_coil_recording_given_to_the_ecore_method():
    refused(simulate(rig="voicecoil_ferrite"), "voicecoil", "not an E-core", "identify")
