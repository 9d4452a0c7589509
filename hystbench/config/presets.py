"""The keys of a rig preset (``rigs/*.toml``) and of a material file (``materials/*.toml``).

A preset is checked once, when it is loaded: the ``actuator`` key chooses the schema (an E-core, a
voice coil and a toroid need different tables; a material file's ``model`` likewise: a Preisach
model, a complex permeability or Rayleigh's law), every table and key is checked for type, unit
range and spelling, the defaults are filled in, and the consumers (physics/presets, the simulated
rig) read the checked values.  A bad preset is refused naming the file, the table and the key
before any simulation starts.
"""

from __future__ import annotations

import math
from typing import Any, Mapping

from ..errors import ConfigError
from .effects import EFFECTS_SCHEMA
from .schema import NUM, OPTIONAL, Key, Schema, check_table

__all__ = ["ACTUATORS", "RIG_SCHEMAS", "MATERIAL_MODELS", "MATERIAL_SCHEMAS", "MATERIAL_SCHEMA", "PREISACH_KINDS",
           "check_rig", "check_material"]

#: Vacuum permeability, H/m (CODATA 2022, as ``scipy.constants.mu_0``).  Written out: importing
#: scipy.constants took 0.3 s of the 0.4 s every command line (``hystbench ctl status``) started in.
MU_0 = 1.25663706127e-06

#: The rig's ``actuator`` key: which physics simulates it.
ACTUATORS = ("ecore", "voicecoil", "toroid")


def _len(doc: str, **rng: float) -> Key:
    return Key(NUM, None, doc, "m", **(rng or {"gt": 0.0}))


def _table(keys: Schema, doc: str, default: Any = None) -> Key:
    return Key(dict, default, doc, table=keys)


_GEOMETRY = {
    "outer_tooth_width_m": _len("width of each outer tooth"),
    "middle_tooth_width_m": _len("width of the middle tooth (the paper: twice the outer tooth's)"),
    "depth_m": _len("depth of the core: the lamination stack length"),
    "slot_width_m": _len("width of each winding slot"),
    "slot_height_m": _len("height of each winding slot"),
    "airgap_m": _len("mechanical clearance between the outer teeth and the mover"),
    "iron_path_length_m": _len("mean magnetic path in iron: middle tooth, half the back iron, outer tooth, mover"),
    "middle_tooth_recess_m": _len("the middle tooth is shorter by this (room for the magnet)", ge=0.0),
    "fringe_height_m": Key(NUM, 0.0, "height where fringing tubes of neighbouring teeth meet (0: no fringing)",
                           "m", ge=0.0),
}
_COIL = {"turns": Key(int, None, "turns of the excitation coil", ge=1)}
_MAGNET = {
    "length_m": _len("length along the middle tooth (its magnetisation direction)"),
    "remanence_t": Key(NUM, None, "remanent flux density Br", "T", gt=0.0),
    "recoil_mu_r": Key(NUM, 1.05, "relative permeability of the recoil line", ge=1.0),
    "conductivity_s_per_m": Key(NUM, 0.0, "electrical conductivity (magnet_eddy_currents)", "S/m", ge=0.0),
    "eddy_radius_m": Key(NUM, 0.0, "radius of each eddy-current loop in the (segmented) magnet", "m", ge=0.0),
}
_IRON = {
    "material": Key(str, None, "a material file (hystbench/config/materials) by name or a .toml path"),
    "lamination_thickness_m": _len("sheet thickness d (lamination_eddy_currents: H_e = sigma d^2/12 dB/dt)"),
    "conductivity_s_per_m": Key(NUM, None, "the sheets' electrical conductivity sigma", "S/m", ge=0.0),
}
_IRON_ECORE = {
    **_IRON,
    "linear_mu_r": Key(NUM, None, "relative permeability of the linearised iron (the analytical model, Eq. 1; "
                       "the simulator's starting slope)", ge=1.0),
    "incremental_mu_r": Key(NUM, OPTIONAL, "incremental (minor-loop) permeability at the magnet's bias, for "
                            "the excitation (left out: linear_mu_r)", ge=1.0),
}
_SENSE = {"turns": Key(int, 1, "turns of the sense coil (sense_V = -turns dflux/dt)", ge=1)}
_AMPLIFIER = {"gain_a_per_v": Key(NUM, None, "current amplifier transconductance", "A/V", gt=0.0)}
_AMPLIFIER_TOROID = {
    **_AMPLIFIER,
    "flux_density_per_a_t": Key(NUM, None, "flux feedback: tesla of B per ampere of nominal command", "T/A",
                                gt=0.0),
}
_INSTRUMENT = {  # load cell + frame and charge amplifier (paper Figs. 8-9)
    # from 1 Hz: below every excitation, a low-pass there passes no force (1e-300 Hz gave scipy's
    # BadCoefficients on the console and a force channel of noise, exit 0)
    "fn_hz": Key(NUM, None, "natural frequency of the load cell and frame", "Hz", ge=1.0),
    "zeta_n": Key(NUM, None, "its damping ratio", gt=0.0),
    "f0_hz": Key(NUM, None, "corner frequency of the charge amplifier's low-pass", "Hz", ge=1.0),
    "zeta_0": Key(NUM, None, "its damping ratio", gt=0.0),
}
_EXCITATION = {
    "frequency_hz": Key(NUM, 320.0, "the operating point's frequency (a simulation's default)", "Hz", gt=0.0),
    "current_pp_a": Key(NUM, 1.0, "the operating point's current, peak to peak", "A", ge=0.0),
}
_VOICECOIL = {
    "force_constant_n_per_a": Key(NUM, None, "Bl: force per ampere", "N/A", gt=0.0),
    "magnet": Key(str, "", "the magnet's material (identification takes ferrite as free of eddy currents)",
                  choices=("ferrite", "ndfeb", "smco")),
    "magnet_conductivity_s_per_m": Key(NUM, 0.0, "the magnet's electrical conductivity", "S/m", ge=0.0),
    "magnet_eddy_depth_m": Key(NUM, 0.0, "eddy-current depth d of the magnet: tau = mu0 sigma d^2 / 12", "m",
                               ge=0.0),
}
_TOROID = {
    "inner_radius_m": _len("inner radius of the ring"),
    "outer_radius_m": _len("outer radius of the ring (> inner_radius_m)"),
    "height_m": _len("height of the ring"),
}

_TOP = {
    "name": Key(str, "", "the preset's name (left out: the file's name)"),
    "description": Key(str, "", "one line on what this rig is"),
    "actuator": Key(str, None, "the physics that simulates it", choices=ACTUATORS),
}
_COMMON = {
    "sense": _table(_SENSE, "the sense coil", {}),
    "amplifier": _table(_AMPLIFIER, "the current amplifier"),
    "excitation": _table(_EXCITATION, "the operating point", {}),
    "effects": Key(dict, {}, "the physical effects that are on, one [effects.NAME] table each (parameters: "
                   "below)", table=EFFECTS_SCHEMA),
}

#: ``actuator`` -> the preset's schema (tables in file order).
RIG_SCHEMAS: Mapping[str, Schema] = {
    "ecore": {**_TOP, "geometry": _table(_GEOMETRY, "the E-core and its mover (paper Sec. V-VI)"),
              "coil": _table(_COIL, "the excitation (magnetising) coil"),
              "magnet": _table(_MAGNET, "the pre-biasing magnet on the middle tooth (left out: none)", OPTIONAL),
              "iron": _table(_IRON_ECORE, "the core's laminated iron"), **_COMMON,
              "instrument": _table(_INSTRUMENT, "the force measurement's two filters (paper Figs. 8-9)")},
    "voicecoil": {**_TOP, "voicecoil": _table(_VOICECOIL, "the voice coil (paper Sec. IV)"), **_COMMON,
                  "instrument": _table(_INSTRUMENT, "the force measurement's two filters (paper Figs. 8-9)")},
    "toroid": {**_TOP, "toroid": _table(_TOROID, "the ring (paper Fig. 4, IEC 60404-4)"),
               "coil": _table(_COIL, "the excitation (magnetising) coil"),
               "iron": _table(_IRON, "the ring's laminated iron"),
               **_COMMON, "amplifier": _table(_AMPLIFIER_TOROID, "the current amplifier in flux feedback")},
}

#: The shapes of the Preisach distribution's components.
PREISACH_KINDS = ("gauss", "lorentz")

_COMPONENT = {
    "kind": Key(str, None, "the component's shape", choices=PREISACH_KINDS),
    "weight": Key(NUM, None, "its share of the distribution", gt=0.0),
    "centre_a_per_m": Key(NUM, None, "its centre", "A/m"),
    "width_a_per_m": Key(NUM, None, "its width", "A/m", gt=0.0),
}
_TERM = {
    "j_t": Key(NUM, None, "polarisation of the term", "T", ge=0.0),
    "h_a_per_m": Key(NUM, None, "its field scale: j_t 2/pi atan(H / h_a_per_m)", "A/m", gt=0.0),
}
#: A material file's ``model`` key: which physics its iron follows (:mod:`hystbench.physics.iron`).
MATERIAL_MODELS = ("preisach-factorised", "complex-permeability", "rayleigh")
_MATERIAL_TOP = {
    "name": Key(str, "", "the material's name (left out: the file's name)"),
    "model": Key(str, "preisach-factorised", "the model's form: chooses the tables below", choices=MATERIAL_MODELS),
}
#: ``model`` -> the material file's schema (tables in file order).
MATERIAL_SCHEMAS: Mapping[str, Schema] = {
    "preisach-factorised": {**_MATERIAL_TOP, "preisach": _table({
        "j_irr_t": Key(NUM, None, "irreversible polarisation at saturation", "T", gt=0.0),
        "h_max_a_per_m": Key(NUM, None, "the Preisach plane's extent, +-h_max", "A/m", gt=0.0),
        "h_scale_a_per_m": Key(NUM, None, "grid warp: H = h_scale sinh(x)", "A/m", gt=0.0),
        "components": Key(list, None, "mu(alpha, beta) = j_irr_t f(alpha) f(-beta) / Z, f = sum of components",
                          items=Key(dict, None, "components", table=_COMPONENT), nonempty=True),
    }, "the irreversible part"),
                            "reversible": _table({
        "terms": Key(list, None, "B_rev(H) = mu0 H + sum of terms", items=Key(dict, None, "terms", table=_TERM)),
    }, "the reversible part")},
    "complex-permeability": {**_MATERIAL_TOP, "permeability": _table({
        "mu_r_real": Key(NUM, None, "mu', the real part of mu_r = mu' - j mu'': B in phase with H per mu0 H",
                         ge=1.0),
        "loss_angle_deg": Key(NUM, None, "delta, tan(delta) = mu''/mu': B lags H by it at the excitation's "
                              "frequency (every excitation frequency: the loss per cycle does not depend on it)",
                              "deg", ge=0.0, lt=90.0),
    }, "linear iron with elliptic B-H loops, H = nu' B + nu''/omega dB/dt (paper Sec. II B)")},
    "rayleigh": {**_MATERIAL_TOP, "rayleigh": _table({
        "initial_mu_r": Key(NUM, None, "mu_i, the initial relative permeability (IEC 60050-221-03-32)", ge=1.0),
        "hysteresis_coefficient_m_per_a": Key(NUM, None, "v, Rayleigh's hysteresis coefficient: B/mu0 = (mu_i + v "
                                              "Hpeak) H +- v/2 (Hpeak^2 - H^2) (IEC 60050-221-03-32)", "m/A",
                                              ge=0.0),
        "region_t": Key(NUM, None, "the Rayleigh region: the largest B amplitude of a loop (about any point) the "
                        "law describes; wider loops are refused; beyond it the initial curve goes on straight "
                        "(the path to a magnet's bias); must be < mu0 mu_i^2 / (2 v)", "T", gt=0.0),
    }, "rate-independent hysteresis with Rayleigh's amplitude law")},
}
#: The schema of the default model (``preisach-factorised``), the one ``hystbench fit-material`` writes.
MATERIAL_SCHEMA: Schema = MATERIAL_SCHEMAS["preisach-factorised"]


def _split(data: Mapping[str, Any]) -> tuple[dict[str, Any], str]:
    body = dict(data)
    source = str(body.pop("_source", body.get("name", "preset")))
    return body, source


def check_rig(data: Mapping[str, Any]) -> dict[str, Any]:
    """A rig preset's dict (as read, with ``_source``: its file) checked against the schema of
    its ``actuator``; returns the checked dict with the defaults filled in."""
    body, source = _split(data)
    kind = body.get("actuator")
    if kind not in ACTUATORS:  # missing or unknown: refused naming the key and the choices
        check_table({"actuator": kind} if "actuator" in body else {}, source, {"actuator": _TOP["actuator"]})
    out = check_table(body, source, RIG_SCHEMAS[kind])
    if kind == "toroid" and not out["toroid"]["outer_radius_m"] > out["toroid"]["inner_radius_m"]:
        raise ConfigError(f"{source} [toroid] outer_radius_m: must be > inner_radius_m = "
                          f"{out['toroid']['inner_radius_m']:g}, got {out['toroid']['outer_radius_m']:g}")
    out["_source"] = source
    return out


def check_material(data: Mapping[str, Any]) -> dict[str, Any]:
    """A material file's dict (with ``_source``) checked; returns it with the defaults filled in."""
    body, source = _split(data)
    model = body.get("model", _MATERIAL_TOP["model"].default)
    if model not in MATERIAL_MODELS:  # refused naming the key and the choices
        check_table({"model": model}, source, {"model": _MATERIAL_TOP["model"]})
    out = check_table(body, source, MATERIAL_SCHEMAS[model])
    if model == "rayleigh":
        _check_rayleigh_region(out["rayleigh"], source)
    out["_source"] = source
    return out


def _check_rayleigh_region(r: Mapping[str, Any], source: str) -> None:
    """The declared Rayleigh region must end before a branch's slope dH/dB = nu_i - c |B - B_r| (and the
    initial curve's, nu_i - 2 c |B|) reaches 0, at amplitude nu_i / (2 c) = mu0 mu_i^2 / (2 v)."""
    v = r["hysteresis_coefficient_m_per_a"]
    limit = math.inf if v == 0.0 else MU_0 * r["initial_mu_r"] ** 2 / (2.0 * v)
    if not r["region_t"] < limit:
        raise ConfigError(f"{source} [rayleigh] region_t: must be < mu0 mu_i^2 / (2 v) = {limit:.4g} T (the largest "
                          f"amplitude before a branch's slope dH/dB reaches 0), got {r['region_t']:g}")
