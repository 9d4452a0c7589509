"""Rig presets and material files are checked once, when they are loaded: a misspelt key, a wrong
type or a value outside its physical range is refused naming the file, the table and the key,
before anything is simulated; every shipped preset passes and reads as its file says."""

from __future__ import annotations

import tomllib
from pathlib import Path

import pytest

from hystbench.config import CONFIG_DIR, load_material, load_rig, material_names, rig_names
from hystbench.errors import ConfigError
from hystbench.sim_backend import SimulatedRig

RIGS = CONFIG_DIR / "rigs"


def _edited(tmp_path: Path, rig: str, old: str, new: str) -> Path:
    text = (RIGS / f"{rig}.toml").read_text(encoding="utf-8")
    assert old in text, old
    path = tmp_path / f"{rig}_edited.toml"
    path.write_text(text.replace(old, new, 1), encoding="utf-8")
    return path


@pytest.mark.parametrize("rig, old, new, expected", [
    # misspelt keys and tables: refused, the known keys named so the right spelling is at hand
    ("ecore_pm", "airgap_m = 0.2e-3", "airgap_mm = 0.2e-3", "[geometry]: unknown key 'airgap_mm'; known: "),
    ("ecore_pm", "[effects.sensor_noise]", "[effects.sensor_nosie]",
     "[effects]: unknown section [effects.sensor_nosie]"),
    ("voicecoil_ferrite", "force_constant_n_per_a", "force_constant", "[voicecoil]: unknown key 'force_constant'"),
    ("ecore", "[sense]", "[sensing]", "unknown section [sensing]"),
    ("ecore_pm", 'actuator = "ecore"', 'actuator = "e-core"', "actuator: must be one of ecore, voicecoil, toroid"),
    # wrong types: turns are counted, a material is named
    ("ecore_pm", "turns = 146", 'turns = "146"', "[coil] turns: must be int"),
    ("ecore_pm", "turns = 146", "turns = 146.5", "[coil] turns: must be int"),
    ("toroid", 'material = "M330-50A"', "material = 330", "[iron] material: must be str"),
    ("ecore_pm", "fn_hz = 4450.0", "fn_hz = true", "[instrument] fn_hz: must be a number"),
    # outside the physical range: a magnet's remanence is > 0, a relative permeability >= 1, a
    # damping ratio > 0, an rms noise >= 0, a length > 0
    ("ecore_pm", "remanence_t = 1.20", "remanence_t = -1.20", "[magnet] remanence_t: must be > 0, got -1.2"),
    ("ecore", "linear_mu_r = 30300", "linear_mu_r = 0.5", "[iron] linear_mu_r: must be >= 1, got 0.5"),
    ("voicecoil_smco", "zeta_n = 0.012", "zeta_n = 0.0", "[instrument] zeta_n: must be > 0, got 0.0"),
    ("ecore_pm", "force_n = 0.03", "force_n = -0.03", "[effects.sensor_noise] force_n: must be >= 0, got -0.03"),
    ("toroid", "height_m = 10e-3", "height_m = -10e-3", "[toroid] height_m: must be > 0"),
    ("ecore_pm", "airgap_m = 0.2e-3", "airgap_m = nan", "[geometry] airgap_m: must be > 0, got nan"),
    ("ecore_pm", "fn_hz = 4450.0", "fn_hz = 1e-300", "[instrument] fn_hz: must be >= 1, got 1e-300"),
    # what the actuator needs, and nothing another actuator needs
    ("voicecoil_ndfeb", "[instrument]", "[instrument_]", "unknown section [instrument_]"),
    ("toroid", "flux_density_per_a_t = 1.0", "", "[amplifier]: missing key 'flux_density_per_a_t'"),
    ("ecore", "[sense]", "[toroid]\ninner_radius_m = 0.1\n[sense]", "unknown section [toroid]"),
    ("toroid", "outer_radius_m = 40e-3", "outer_radius_m = 20e-3", "[toroid] outer_radius_m: must be > inner_radius_m"),
    ("ecore_pm", 'material = "M330-50A"', 'material = "M330-35A"', "[iron] material: unknown material 'M330-35A'"),
])
def test_a_bad_rig_key_is_refused_at_load_naming_file_table_and_key(tmp_path: Path, rig, old, new, expected) -> None:
    path = _edited(tmp_path, rig, old, new)
    with pytest.raises(ConfigError) as info:
        load_rig(path)
    msg = str(info.value)
    assert msg.startswith(str(path)) and expected in msg, msg


def test_the_simulator_refuses_a_bad_preset_before_it_simulates(tmp_path: Path) -> None:
    """The rig is built from the checked preset: a misspelt magnet key never reaches the MEC (before,
    ``recoil_mur`` was ignored and the default recoil permeability silently used)."""
    path = _edited(tmp_path, "ecore_pm", "recoil_mu_r = 1.05", "recoil_mur = 1.05")
    with pytest.raises(ConfigError, match=r"\[magnet\]: unknown key 'recoil_mur'; known: .*recoil_mu_r"):
        SimulatedRig(str(path))
    preset = tomllib.loads(path.read_text(encoding="utf-8"))  # a dict is checked the same way
    with pytest.raises(ConfigError, match=r"\[magnet\]: unknown key 'recoil_mur'"):
        SimulatedRig(preset)


@pytest.mark.parametrize("name", rig_names())
def test_every_shipped_preset_passes_and_reads_as_written(name: str) -> None:
    raw = tomllib.loads((RIGS / f"{name}.toml").read_text(encoding="utf-8"))
    rig = load_rig(name)
    assert rig["name"] == name and rig["_source"] == str(RIGS / f"{name}.toml")
    for table, body in raw.items():
        if table == "effects":
            continue
        if not isinstance(body, dict):
            assert rig[table] == body
            continue
        for key, value in body.items():  # numbers read as written (ints as floats where a number is meant)
            assert rig[table][key] == value and type(rig[table][key]) in (type(value), float), (table, key)
    for effect, params in raw.get("effects", {}).items():
        assert {k: rig["effects"][effect][k] for k in params} == params
    assert load_rig(rig) == rig  # checking a checked preset changes nothing


def test_defaults_are_filled_in_and_optional_tables_stay_out() -> None:
    """What the consumers used to assume with .get(): one sense turn, no magnet on the plain E-core,
    the catalogue's parameters for an effect listed without any."""
    vc = load_rig("voicecoil_ferrite")
    assert vc["sense"] == {"turns": 1}
    ecore = load_rig("ecore")
    assert "magnet" not in ecore and ecore["geometry"]["fringe_height_m"] == 5e-3
    assert ecore["effects"]["static_hysteresis"] == {}
    assert ecore["effects"]["adc_quantisation"]["bits"] == 16  # a 16-bit ADC unless the preset says otherwise
    assert load_rig("ecore_pm")["magnet"]["recoil_mu_r"] == 1.05


@pytest.mark.parametrize("name", material_names())
def test_every_shipped_material_passes(name: str) -> None:
    m = load_material(name)
    tables = {"preisach-factorised": "preisach", "complex-permeability": "permeability", "rayleigh": "rayleigh"}
    assert m["name"] == name and tables[m["model"]] in m  # each model's own table (config/presets.py)
    assert m["model"] != "preisach-factorised" or len(m["preisach"]["components"]) >= 1


def test_a_bad_material_key_is_refused_naming_file_and_key(tmp_path: Path) -> None:
    text = (CONFIG_DIR / "materials" / "M330-50A.toml").read_text(encoding="utf-8")
    for old, new, expected in [
        ("h_scale_a_per_m = ", "h_scale = ", "[preisach]: unknown key 'h_scale'"),
        ('kind = "lorentz"', 'kind = "cauchy"', "[preisach.components[1]] kind: must be one of gauss, lorentz"),
        ("j_t = 0.2764103763", "j_t = -0.27", "[reversible.terms[0]] j_t: must be >= 0, got -0.27"),
    ]:
        path = tmp_path / "M.toml"
        path.write_text(text.replace(old, new, 1), encoding="utf-8")
        with pytest.raises(ConfigError) as info:
            load_material(path)
        assert str(info.value).startswith(str(path)) and expected in str(info.value), str(info.value)
