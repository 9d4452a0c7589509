"""The simulated rig, with its full preset physics (Preisach iron, eddy currents), at the paper's
operating points, and its flux lag as the paper's Figs. 16-17 imply."""

import numpy as np
import pytest

from hystbench.config import load_rig
from hystbench.physics import presets
from hystbench.sim_backend.rig import SimulatedRig

QUIET = {"sensor_noise": False, "adc_quantisation": False}


def period_average(rig, block, name):
    n = int(round(rig.fs_hz / rig.frequency_hz))
    k = len(block.channels[name]) // n
    return block.channels[name][-k * n:].reshape(k, n).mean(axis=0)


@pytest.mark.parametrize("rig_name, ipp, lo, hi", [("ecore", 1.27, 0.0, 3.3), ("ecore_pm", 1.4, 125.0, 220.0)])
def test_simulated_force_range_is_the_papers(rig_name, ipp, lo, hi):
    # Paper Sec. VI: 0-3.3 N at 1.27 A-pp, 125-220 N at 1.4 A-pp; within 10 % (the tolerance).
    rig = SimulatedRig(rig_name, frequency_hz=40.0, current_pp_a=ipp, generator_clock_ppm=0.0,
                       effects={**QUIET, "instrument_filter": False})
    force = period_average(rig, rig.record(0.1), "force_N")
    assert force.min() == pytest.approx(lo, abs=0.1 * max(lo, 1.0))
    assert force.max() == pytest.approx(hi, rel=0.10)


@pytest.mark.parametrize("rig_name, ipp", [("ecore", 1.27), ("ecore_pm", 1.4)])
def test_analytical_model_follows_the_rig_to_the_papers_accuracy(rig_name, ipp):
    # The paper's non-hysteretic model is 98.5 % / 98.7 % accurate; ours, against the simulated
    # rig's quasi-static loop (which holds hysteresis the model lacks), must be within 2.5 %.
    rig = SimulatedRig(rig_name, frequency_hz=40.0, current_pp_a=ipp, generator_clock_ppm=0.0,
                       effects={**QUIET, "instrument_filter": False})
    block = rig.record(0.1)
    i, force = period_average(rig, block, "current_A"), period_average(rig, block, "force_N")
    model = presets.ecore_mec(load_rig(rig_name), linear_iron=True).force(i)
    assert np.max(np.abs(model - force)) / np.ptp(force) < 0.025


def flux_lag_deg(rig_name, f):
    rig = SimulatedRig(rig_name, frequency_hz=f, effects=QUIET)
    block = rig.record(0.1)
    t = block.time_s()
    w = 2 * np.pi * rig.generator_frequency_hz
    n = int(np.floor(len(t) * rig.generator_frequency_hz / rig.fs_hz) * rig.fs_hz / rig.generator_frequency_hz)
    ph = lambda x: np.angle(np.sum((x[:n] - x[:n].mean()) * np.exp(-1j * w * t[:n])))  # noqa: E731
    return np.degrees(ph(block.channels["current_A"]) - ph(block.channels["flux_Wb"]))


@pytest.mark.parametrize("rig_name", ["ecore", "ecore_pm"])
def test_flux_lags_current_by_tenths_to_a_few_degrees_growing_with_frequency(rig_name):
    lags = [flux_lag_deg(rig_name, f) for f in (40.0, 160.0, 480.0)]
    assert all(0.1 < lag < 5.0 for lag in lags)
    assert lags[0] < lags[1] < lags[2]


def test_hysteresis_is_what_makes_the_low_frequency_lag():
    # With the static hysteresis off only eddy currents remain, whose lag vanishes as f -> 0.
    rig = SimulatedRig("ecore", frequency_hz=40.0, effects={**QUIET, "static_hysteresis": False})
    block = rig.record(0.1)
    t = block.time_s()
    w = 2 * np.pi * rig.generator_frequency_hz
    ph = lambda x: np.angle(np.sum((x - x.mean()) * np.exp(-1j * w * t)))  # noqa: E731
    eddy_only = np.degrees(ph(block.channels["current_A"]) - ph(block.channels["flux_Wb"]))
    assert eddy_only < 0.3 * flux_lag_deg("ecore", 40.0)
