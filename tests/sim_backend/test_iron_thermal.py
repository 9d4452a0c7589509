"""``iron_thermal_drift`` (hystbench.physics.iron_thermal): the iron's static field scales by
1 + a_T (dT/dt) t along the rig's clock.  Checked against what that scaling implies on its own: the
flux-controlled toroid's loop encloses exactly that share of the cold loop's energy (B is imposed, so
H scales and nothing else moves); on the E-cores, where the airgap carries most of the MMF, the
hysteresis lag of flux behind current is the iron's loss field over the whole MMF, so it scales by
the same factor to first order; and the samples do not depend on how the stream is cut into blocks."""

import math

import numpy as np
import pytest

from hystbench.errors import ConfigError
from hystbench.sim_backend.rig import SimulatedRig

QUIET = {"sensor_noise": False, "adc_quantisation": False}
#: the static loop alone: no eddy or rate field, which the temperature does not scale
STATIC = {**QUIET, "lamination_eddy_currents": False}


def warmed(rig: SimulatedRig, seconds: float) -> SimulatedRig:
    """The rig ``seconds`` later on its own clock (the iron warms from the rig's start)."""
    rig.skip(int(round(seconds * rig.fs_hz)))
    return rig


def toroid_loop_energy(effects: dict, later_s: float) -> float:
    """The energy per cycle and volume (J/m^3) the toroid's steady loop encloses at 50 Hz."""
    rig = warmed(SimulatedRig("toroid", frequency_hz=50.0, current_pp_a=1.6, effects={**STATIC, **effects}), later_s)
    block = rig.record(3.0 / 50.0)
    n = int(round(rig.fs_hz / rig.generator_frequency_hz))
    h = block.channels["current_A"][-n:] * rig.actuator.turns / rig.actuator.path_m
    b = block.channels["flux_Wb"][-n:] / rig.actuator.area_m2
    return float(np.sum(h * 0.5 * (np.roll(b, -1) - np.roll(b, 1))))


@pytest.mark.parametrize(("kelvin_per_s", "tc", "max_rise", "expected"),
                         [(2.0, -0.005, 60.0, 1 - 0.005 * 20.0), (2.0, 0.004, 60.0, 1 + 0.004 * 20.0),
                          (2.0, -0.005, 5.0, 1 - 0.005 * 5.0)], ids=["narrows", "widens", "levels_off"])
def test_toroid_loop_energy_scales_by_the_temperature_coefficient(kelvin_per_s, tc, max_rise, expected):
    """10 s of warming at 2 K/s: 20 K (or the 5 K it levels off at) times a_T; the loop's energy moves by
    that share while the 3-period record adds 0.06 K more."""
    cold = toroid_loop_energy({}, 10.0)
    warm = toroid_loop_energy({"iron_thermal_drift": {"kelvin_per_s": kelvin_per_s, "field_tc_per_k": tc,
                                                      "max_rise_k": max_rise}}, 10.0)
    assert warm / cold == pytest.approx(expected, abs=2e-3 * abs(tc) / 0.005)


def fundamental(x: np.ndarray, f_hz: float, fs_hz: float) -> complex:
    t = np.arange(x.size) / fs_hz
    return 2 * np.mean(x * np.exp(-2j * np.pi * f_hz * t))


def flux_lag_deg(rig_name: str, effects: dict, later_s: float) -> float:
    rig = warmed(SimulatedRig(rig_name, seed=1, effects={**STATIC, **effects}), later_s)
    rig.set_excitation(frequency_hz=40.0, current_pp_a=1.4)
    rig.record(0.2)
    block = rig.record(0.25)
    i = fundamental(block.channels["current_A"], 40.0, block.fs_hz)
    phi = fundamental(block.channels["flux_Wb"], 40.0, block.fs_hz)
    return math.degrees(np.angle(i / phi))


@pytest.mark.parametrize("rig_name", ["ecore", "ecore_pm"])
@pytest.mark.parametrize("scale", [0.9, 0.6])
def test_ecore_hysteresis_lag_follows_the_scale(rig_name, scale):
    """The iron's field at scale s after (1 - s) / 0.01 K: the lag becomes about s times the cold one
    (within 6 % of 1 - s: the iron's own share of the MMF and the magnet's bias move it a little)."""
    cold = flux_lag_deg(rig_name, {}, 0.0)
    rise = (1.0 - scale) / 0.01
    warm = flux_lag_deg(rig_name, {"iron_thermal_drift": {"kelvin_per_s": 1.0, "field_tc_per_k": -0.01,
                                                          "max_rise_k": 80.0}}, rise)
    assert cold > 0.3
    assert abs(warm / cold - scale) <= 0.06 * (1.0 - scale)


def test_ecore_drift_does_not_depend_on_the_cut_into_blocks():
    def run(block_size: int) -> np.ndarray:
        rig = SimulatedRig("ecore_pm", seed=3, effects={**QUIET, "iron_thermal_drift": {"kelvin_per_s": 10.0}})
        rig.set_excitation(frequency_hz=160.0, current_pp_a=1.4)
        return np.concatenate([b.channels["flux_Wb"] for b in rig.blocks(block_size, duration_s=0.05)])

    a, b = run(5000), run(1237)
    assert np.max(np.abs(a - b)) <= 5e-5 * np.ptp(a)  # the fixed point's own tolerance (as the rate terms')


def test_a_rise_that_would_reverse_the_loop_is_refused():
    with pytest.raises(ConfigError, match="iron_thermal_drift.max_rise_k"):
        SimulatedRig("ecore", effects={"iron_thermal_drift": {"max_rise_k": 200.0}})
