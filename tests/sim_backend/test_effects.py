"""The effect catalogue: public names, switching and parameter parsing."""

import pytest

from hystbench.errors import ConfigError
from hystbench.sim_backend.effects import CATALOGUE, parse_effect_args, resolve_effects

DESIGN_NAMES = {  # ../shared/design.md, "Names of physical effects (a public interface)"
    "static_hysteresis", "lamination_eddy_currents", "magnet_eddy_currents", "iron_saturation",
    "instrument_filter", "frame_resonance", "charge_amp_highpass", "integrator_leak",
    "channel_skew", "force_offset_drift", "magnet_thermal_drift", "load_cell_compliance",
    "mains_pickup", "amplifier_distortion", "sensor_noise", "adc_quantisation",
}


def test_catalogue_is_exactly_the_design_names_each_with_a_description():
    assert set(CATALOGUE) == DESIGN_NAMES
    assert all(len(e.description) > 20 for e in CATALOGUE.values())


def test_effects_are_off_unless_listed():
    assert resolve_effects({}) == {}
    on = resolve_effects({"sensor_noise": {"force_n": 0.5}})
    assert on["sensor_noise"]["force_n"] == 0.5
    assert on["sensor_noise"]["current_a"] == CATALOGUE["sensor_noise"].defaults["current_a"]


def test_command_line_switches_and_parameters():
    over = parse_effect_args(["sensor_noise=off", "charge_amp_highpass=0.5", "channel_skew.force_N=3e-6",
                              "mains_pickup=on"])
    active = resolve_effects({"sensor_noise": {}}, over)
    assert "sensor_noise" not in active
    assert active["charge_amp_highpass"]["time_constant_s"] == 0.5
    assert active["channel_skew"]["force_N"] == 3e-6
    assert active["mains_pickup"] == dict(CATALOGUE["mains_pickup"].defaults)


@pytest.mark.parametrize("arg, words", [
    ("bogus=on", "unknown effect 'bogus'"),
    ("sensor_noise", "expected NAME=VALUE"),
    ("sensor_noise=loud", "not on/off or a number"),
    ("channel_skew=1e-6", "use channel_skew.PARAM=VALUE"),
    ("sensor_noise.volume=1", "no parameter 'volume'"),
])
def test_bad_effect_arguments_name_the_argument(arg, words):
    with pytest.raises(ConfigError, match=words):
        parse_effect_args([arg])


def test_unknown_parameter_in_a_preset_names_file_and_table():
    with pytest.raises(ConfigError, match=r"rig.toml \[effects.sensor_noise\].*'volume'"):
        resolve_effects({"sensor_noise": {"volume": 3}}, where="rig.toml")
