"""The effect catalogue (hystbench.config.effects): public names, switching and parameter parsing."""

import pytest

from hystbench.errors import ConfigError
from hystbench.config.effects import CATALOGUE, parse_effect_args, resolve_effects, validate_effects

DESIGN_NAMES = {  # ../shared/design.md, "Names of physical effects (a public interface)"
    "static_hysteresis", "lamination_eddy_currents", "magnet_eddy_currents", "iron_saturation",
    "instrument_filter", "frame_resonance", "charge_amp_highpass", "integrator_leak",
    "channel_skew", "force_offset_drift", "magnet_thermal_drift", "load_cell_compliance",
    "mains_pickup", "amplifier_distortion", "sensor_noise", "adc_quantisation",
}
#: design.md: "New effects (for example the rate dependence real magnetic materials show) join the
#: catalogue with names in the same style" (issue 28): Bertotti's excess field and a relaxation, and the
#: loop's temperature coefficient (its iron warming along the day, as the magnet's does).
RATE_NAMES = {"excess_loss", "magnetic_relaxation"}
TEMPERATURE_NAMES = {"iron_thermal_drift"}


def test_catalogue_is_exactly_the_design_names_each_with_a_description():
    assert set(CATALOGUE) == DESIGN_NAMES | RATE_NAMES | TEMPERATURE_NAMES
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
    ("sensor_noise.=1", "no parameter name after 'sensor_noise.'"),
])
def test_bad_effect_arguments_name_the_argument(arg, words):
    with pytest.raises(ConfigError, match=words):
        parse_effect_args([arg])


def test_unknown_parameter_in_a_preset_names_file_and_table():
    with pytest.raises(ConfigError, match=r"rig.toml \[effects.sensor_noise\].*'volume'"):
        resolve_effects({"sensor_noise": {"volume": 3}}, where="rig.toml")


# --- ranges (issue 10): a value outside a parameter's physical range is refused, wherever it comes from
def test_every_parameter_has_a_range_that_holds_its_default():
    for e in CATALOGUE.values():
        assert set(e.ranges) == set(e.defaults), e.name
        for k, v in e.defaults.items():
            assert e.params[k].problem(v) is None, f"{e.name}.{k} = {v}"
            for item in (v if isinstance(v, list) else [v]):
                assert k not in e.nyquist or item < 100_000.0 / 2, f"{e.name}.{k} = {item}"


@pytest.mark.parametrize("name, param, bad", [
    ("charge_amp_highpass", "time_constant_s", 0.0),  # a time constant is > 0
    ("integrator_leak", "time_constant_s", -1.0),
    ("load_cell_compliance", "stiffness_n_per_m", 0.0),
    ("mains_pickup", "third_harmonic", 1.0),  # a fraction in [0, 1)
    ("sensor_noise", "force_n", -0.01),  # an rms is >= 0
    ("channel_skew", "force_N", -2e-6),  # a delay: the ADC cannot sample before the event
    ("adc_quantisation", "bits", 12.5),
    ("adc_quantisation", "force_n", 0.0),  # a full scale is > 0
    ("frame_resonance", "depth", -1.0),  # gain 1 + depth at the mode: 0 would be a perfect notch
    ("magnet_thermal_drift", "remanence_tc_per_k", 0.001),  # magnets lose remanence when warmed
    ("force_offset_drift", "offset_n", float("nan")),
    ("amplifier_distortion", "second", float("inf")),
])
def test_a_value_outside_its_range_names_effect_param_value_and_range(name, param, bad):
    rng = CATALOGUE[name].params[param].range_text() or "finite"
    for where, call in (("--effect", lambda: parse_effect_args([f"{name}.{param}={bad}"])),
                        ("rig.toml", lambda: resolve_effects({name: {param: bad}}, where="rig.toml")),
                        ("daemon.toml [source] effects",
                         lambda: validate_effects({name: {param: bad}}, "daemon.toml [source] effects"))):
        with pytest.raises(ConfigError) as err:
            call()
        msg = str(err.value)
        assert msg.startswith(where) and name in msg and f"{param}: must be" in msg and rng in msg, msg
        assert msg.endswith(f"got {bad!r}"), msg


def test_frequencies_must_be_below_half_the_sample_rate_once_it_is_known():
    table = {"frame_resonance": {"frequencies_hz": [850.0, 30_000.0]}}
    assert validate_effects(table, "x")["frame_resonance"]["frequencies_hz"] == [850.0, 30_000.0]
    with pytest.raises(ConfigError, match=r"frame_resonance.frequencies_hz: must be below fs/2 = 25000 Hz, got 30000"):
        validate_effects(table, "x", fs_hz=50_000.0)


@pytest.mark.parametrize("name", ["charge_amp_highpass", "integrator_leak"])
def test_a_filters_corner_must_be_below_half_the_sample_rate_once_it_is_known(name):
    """1e-300 s was taken: scipy's BadCoefficients on the console and a channel of noise, exit 0.  The
    bound is 1/(pi fs): the corner 1/(2 pi tau) at fs/2."""
    fs = 100_000.0
    assert validate_effects({name: 3.2e-6}, "x", fs_hz=fs)[name]["time_constant_s"] == 3.2e-6  # just above
    for tau in (3.1e-6, 1e-300):
        with pytest.raises(ConfigError, match=rf"{name}.time_constant_s: must be above 1/\(pi fs\) = 3.18e-06 s "
                                              rf"\(its corner 1/\(2 pi tau\) below fs/2 = 50000 Hz\), got {tau!r}"):
            validate_effects({name: tau}, "x", fs_hz=fs)
    assert validate_effects({name: 1e-300}, "x")[name]["time_constant_s"] == 1e-300  # no fs: nothing to judge by


def test_a_load_cell_softer_than_one_newton_per_metre_is_refused():
    """1e-300 N/m overflowed 1/k: a NaN force instead of the refusal a soft load cell gets."""
    with pytest.raises(ConfigError, match=r"load_cell_compliance.stiffness_n_per_m: must be >= 1, got 1e-300"):
        validate_effects({"load_cell_compliance": 1e-300}, "x")


def test_the_daemons_effects_table_takes_switches_numbers_and_tables():
    """daemon.toml documents { sensor_noise = false, frame_resonance = -0.2 }: a bare number is the
    primary parameter (the depth of the frame modes: -0.2 is a dip of 20 % at each mode)."""
    on = validate_effects({"sensor_noise": False, "frame_resonance": -0.2, "mains_pickup": True,
                           "charge_amp_highpass": {"time_constant_s": 0.5}}, "daemon.toml [source] effects")
    assert set(on) == {"frame_resonance", "mains_pickup", "charge_amp_highpass"}
    assert on["frame_resonance"]["depth"] == -0.2 and on["frame_resonance"]["zeta"] == 0.02
    assert on["charge_amp_highpass"]["time_constant_s"] == 0.5
    for bad, words in [({"sensor_noise": "loud"}, "true/false, a number or a table"),
                       ({"channel_skew": 1e-6}, "several parameters"),
                       ({"bogus": True}, "unknown effect 'bogus'"),
                       ({"sensor_noise": {"force_n": True}}, "must be a number")]:
        with pytest.raises(ConfigError, match=words) as err:
            validate_effects(bad, "daemon.toml [source] effects")
        assert str(err.value).startswith("daemon.toml [source] effects")


def test_0_and_1_are_numbers_not_switches():
    """mains_pickup=1 meant "on, 0.2 mV" before; a number sets the primary parameter: 1 V."""
    assert parse_effect_args(["mains_pickup=1"]) == {"mains_pickup": {"sense_v": 1.0}}
    assert parse_effect_args(["sensor_noise=0"]) == {"sensor_noise": {"force_n": 0.0}}
