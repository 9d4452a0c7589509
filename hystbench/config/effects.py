"""The catalogue of switchable physical effects of the simulated rig, and how they are switched.

The names are a public interface: later tools name these effects when they explain why a recording
differs from the simulation.  Every effect is off unless a rig preset lists it (``[effects.NAME]``,
optionally overriding parameters) or the user switches it on (``--effect NAME=on``, the daemon's
``[source] effects``).

Every parameter is a :class:`~hystbench.config.schema.Key` with its physical range: a negative
time constant or a frame mode above the Nyquist frequency would give numbers with no meaning and no
error, so a value outside its range is a ConfigError naming where it came from (a rig preset,
``--effect``, the daemon's ``[source] effects``), ``EFFECT.param``, the value and the range.  The
catalogue lives with the configuration because a rig preset's ``[effects]`` tables are checked
when the preset is loaded; frequencies are checked against fs/2 once the sample rate is known.
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any, Iterable, Mapping

from ..errors import ConfigError
from .schema import NUM, OPTIONAL, Key, check_table, check_value

__all__ = ["Effect", "CATALOGUE", "EFFECTS_SCHEMA", "resolve_effects", "parse_effect_args", "validate_effects"]


@dataclass(frozen=True)
class Effect:
    """One switchable physical effect of the simulated rig with its parameters' schema, so the
    catalogue, the checks and ``hystbench effects`` read one description."""

    name: str
    description: str  # one line of physics
    params: Mapping[str, Key]  # one per parameter (a list parameter: its items' range)
    primary: str | None = None  # the parameter that ``NAME=<number>`` sets
    nyquist: tuple[str, ...] = field(default=())  # frequencies: also < fs/2 once fs is known
    #: time constants of a filter on a sampled channel: its corner 1/(2 pi tau) also below fs/2 once fs is
    #: known (a high-pass of 1e-300 s gave scipy's BadCoefficients and a force channel of noise, exit 0)
    sampled_corners: tuple[str, ...] = field(default=())

    @property
    def defaults(self) -> Mapping[str, Any]:
        return MappingProxyType({k: p.default for k, p in self.params.items()})

    @property
    def ranges(self) -> Mapping[str, str]:
        """Each parameter's legal values in interval notation, as ``hystbench effects`` lists them:
        '(0, inf)', '[0, 1)', '(0, fs/2)' for a frequency, '[2, 32], whole'."""
        return MappingProxyType({k: _interval(p, k in self.nyquist) for k, p in self.params.items()})


def _interval(key: Key, below_nyquist: bool) -> str:
    k = key.items if key.items is not None else key
    lo, lo_open = (k.gt, True) if k.gt is not None else (k.ge, False) if k.ge is not None else (None, True)
    hi, hi_open = (k.lt, True) if k.lt is not None else (k.le, False) if k.le is not None else (None, True)
    low = "-inf" if lo is None else f"{lo:g}"
    high = "fs/2" if below_nyquist and hi is None else "inf" if hi is None else f"{hi:g}"
    return f"{'(' if lo_open else '['}{low}, {high}{')' if hi_open else ']'}" + (", whole" if k.whole else "")


def _e(name: str, description: str, primary: str | None = None, nyquist: tuple[str, ...] = (),
       sampled_corners: tuple[str, ...] = (), **params: Key) -> Effect:
    return Effect(name, description, MappingProxyType(params), primary, nyquist, sampled_corners)


def _num(default: float, doc: str, unit: str = "", **rng: float) -> Key:
    return Key(NUM, default, doc, unit, **rng)


def _skew(default: float, channel: str) -> Key:  # a delay (the rig cannot lead), up to 1 ms
    return _num(default, f"{channel} is sampled this much after the common clock", "s", ge=0.0, le=1e-3)


def _rms(default: float, channel: str, unit: str) -> Key:
    return _num(default, f"rms noise on {channel}", unit, ge=0.0)


def _full_scale(default: float, channel: str, unit: str) -> Key:
    return _num(default, f"full scale of {channel} (+-)", unit, gt=0.0)


def _distortion(default: float, doc: str, unit: str) -> Key:  # small enough for a monotonic amplifier
    return _num(default, doc, unit, ge=-0.1, le=0.1)


_CHANNELS = (("current_A", "current_a", "A"), ("force_N", "force_n", "N"), ("flux_Wb", "flux_wb", "Wb"),
             ("sense_V", "sense_v", "V"), ("command_V", "command_v", "V"))

CATALOGUE: Mapping[str, Effect] = MappingProxyType({e.name: e for e in [
    _e("static_hysteresis",
       "rate-independent iron hysteresis (Preisach model fitted to the real loops): flux lags current"),
    _e("lamination_eddy_currents",
       "eddy currents in the laminations, H_e = sigma d^2/12 dB/dt: lag growing with frequency"),
    _e("excess_loss",
       "Bertotti's excess (domain-wall) field k (sqrt(|dB/dt| + r0) - sqrt(r0)) sign(dB/dt) in the iron: "
       "a lag and a loss per cycle growing as sqrt(f), falling with amplitude as B^-0.5 relative to the loop",
       "coefficient_a_per_m_per_sqrt_t_per_s",
       coefficient_a_per_m_per_sqrt_t_per_s=_num(
           0.3, "k = sqrt(sigma G S V0); the loss per cycle under a sine is 8.76 k B^1.5 f^0.5 (J/m^3)",
           "A/m per sqrt(T/s)", ge=0.0, le=100.0),
       knee_rate_t_per_s=_num(1.0, "r0 = n0^2 V0 / (4 sigma G S): below this rate the field is linear in dB/dt",
                              "T/s", gt=0.0)),
    _e("magnetic_relaxation",
       "the iron's field holds a share of B's recent change and lets it go with a time constant "
       "(a Debye after-effect): a loss peaking at w tau = 1, and loss after B stops changing",
       "time_constant_s",
       time_constant_s=_num(1e-3, "tau, the relaxation's time constant", "s", gt=0.0, le=10.0),
       reluctivity_a_per_m_per_t=_num(
           40.0, "kappa, the reluctivity it adds to changes faster than tau (H_rel = kappa (B - B_slow))",
           "A/m per T", ge=0.0)),
    _e("magnet_eddy_currents",
       "eddy currents in a conducting magnet (NdFeB, SmCo) oppose flux change: extra lag"),
    _e("iron_saturation",
       "the iron's single-valued B-H curve bends towards saturation instead of staying linear (Preisach "
       "materials only: refused for a complex-permeability or Rayleigh iron, which have no saturation)"),
    _e("instrument_filter",
       "load cell + frame and charge amplifier as two 2nd-order low-passes (paper Figs. 8-9)"),
    _e("frame_resonance",
       "small extra frame modes (paper Fig. 7c peaks near 850 and 1175 Hz)", "depth", ("frequencies_hz",),
       frequencies_hz=Key(list, [850.0, 1175.0], "the modes' frequencies, each below fs/2", "Hz",
                          items=Key(NUM, None, "frequencies", "Hz", gt=0.0)),
       zeta=_num(0.02, "damping ratio of each mode", gt=0.0, le=1.0),
       depth=_num(0.2, "gain 1 + depth at each mode: > 0 a peak, < 0 a dip (-1 would be a perfect notch); "
                  "at most 100 (40 dB: a frame mode, not a second load cell)", gt=-1.0, le=100.0),
       split=_num(0.0, "the mode's anti-resonance sits this share above (> 0) or below (< 0) its resonance "
                  "(a frame's two masses: the gain steps across the mode); 0: a pure peak", ge=-0.5, le=0.5)),
    _e("charge_amp_highpass",
       "piezo charge leaks through the charge amplifier's time constant: force high-passed",
       "time_constant_s", sampled_corners=("time_constant_s",),
       time_constant_s=_num(1.0, "the charge amplifier's time constant (a long one: 1e5 s; beyond 1e6 s no "
                                 "high-pass is left to simulate)", "s", gt=0.0, le=1e6)),
    _e("integrator_leak",
       "the flux integrator is lossy (1/(s + 1/tau)): flux high-passed, a phase lead at low f",
       "time_constant_s", sampled_corners=("time_constant_s",),
       time_constant_s=_num(1.0, "the integrator's leak time constant (beyond 1e6 s: no leak left to simulate)",
                            "s", gt=0.0, le=1e6)),
    _e("channel_skew",
       "the ADC channels are not sampled at the same instant: per-channel delays in seconds",
       **{ch: _skew(d, ch) for (ch, _, _), d in zip(_CHANNELS, (0.0, 2e-6, 1e-6, 0.0, 0.0))}),
    _e("force_offset_drift",
       "charge-amplifier output offset and its slow drift (leakage current)", "drift_n_per_s",
       offset_n=_num(0.05, "force offset at the start", "N"),
       drift_n_per_s=_num(0.01, "drift of the offset", "N/s")),
    _e("magnet_thermal_drift",
       "magnet remanence falls as the magnet warms: bias force drifts", "kelvin_per_s",
       kelvin_per_s=_num(0.01, "the magnet's warming rate (a few K per minute; 10 K/s is already a fault)",
                         "K/s", ge=-10.0, le=10.0),
       # reversible Br coefficient: -0.03 (SmCo) to -0.2 %/K (ferrite); magnets lose remanence when warmed
       remanence_tc_per_k=_num(-0.0012, "relative change of remanence per kelvin", "1/K", ge=-0.01, le=0.0)),
    _e("iron_thermal_drift",
       "the iron warms along the day and its loop follows its temperature coefficient: the static field "
       "H(B) scales by 1 + a_T dT, so the iron's reluctivity and hysteresis delay drift with the clock",
       "kelvin_per_s",
       kelvin_per_s=_num(0.01, "the iron's warming rate (the coil's losses; a few K per minute)", "K/s",
                         ge=-10.0, le=10.0),
       # MnZn ferrites below their loss minimum: the loop narrows, -0.3 to -1 %/K; steels less
       field_tc_per_k=_num(-0.005, "a_T, the static field's relative change per kelvin", "1/K", ge=-0.01, le=0.01),
       max_rise_k=_num(60.0, "where the warming levels off (|a_T| max_rise_k <= 0.8: the loop never reverses)",
                       "K", gt=0.0, le=80.0)),
    _e("load_cell_compliance",
       "the load cell yields under force, so the airgap closes by F/k", "stiffness_n_per_m",
       # from 1 N/m (a load cell a hundred million times softer than a real one): 1e-300 made the gap's
       # change 1/k overflow, a NaN force instead of the refusal 1e-100 gets ("the gap closes")
       stiffness_n_per_m=_num(1.0e9, "the load cell's stiffness k", "N/m", ge=1.0)),
    _e("mains_pickup",
       "50 Hz and its 3rd harmonic picked up by the sense leads and the charge amplifier", "sense_v",
       ("frequency_hz",),
       frequency_hz=_num(50.0, "mains frequency, below fs/2", "Hz", gt=0.0),
       sense_v=_num(2e-4, "amplitude on sense_V", "V", ge=0.0),
       force_n=_num(0.002, "amplitude on force_N", "N", ge=0.0),
       third_harmonic=_num(0.3, "3rd harmonic relative to the fundamental", ge=0.0, lt=1.0)),
    _e("amplifier_distortion",
       "current amplifier's static nonlinearity: 2nd and 3rd harmonics in the coil current", "second",
       second=_distortion(0.002, "i = i0 + second i0^2 + third i0^3", "1/A"),
       third=_distortion(0.001, "(see second)", "1/A^2")),
    _e("sensor_noise",
       "white noise on every measured channel (rms values per channel)", "force_n",
       **{p: _rms(d, ch, u) for (ch, p, u), d in sorted(zip(_CHANNELS, (2e-4, 0.01, 2e-8, 2e-4, 1e-4)),
                                                        key=lambda c: c[0][1] != "force_n")}),
    _e("adc_quantisation",
       "16-bit ADC on every channel: rounding to the LSB of each channel's full scale, clipping",
       bits=Key(NUM, 16, "ADC resolution", "bits", ge=2, le=32, whole=True),
       **{p: _full_scale(d, ch, u) for (ch, p, u), d in zip(_CHANNELS, (2.0, 500.0, 1e-4, 1.0, 10.0))}),
]})

#: A rig preset's ``[effects]`` table: one optional sub-table per effect (listed: on).
EFFECTS_SCHEMA: Mapping[str, Key] = MappingProxyType(
    {e.name: Key(dict, OPTIONAL, e.description, table=e.params) for e in CATALOGUE.values()})

_ON = {"on", "true", "yes"}
_OFF = {"off", "false", "no"}  # not "0"/"1": NAME=0 and NAME=1 are numbers for the primary parameter


def _check_against_fs(effect: Effect, params: Mapping[str, Any], place: str, prefix: str, fs_hz: float | None) -> None:
    """Once fs is known: each frequency below fs/2, each sampled filter's corner too."""
    if fs_hz is None:
        return
    for p in effect.nyquist:
        for item in (params[p] if isinstance(params[p], list) else [params[p]]):
            if not item < fs_hz / 2:
                raise ConfigError(f"{place} {prefix}{p}: must be below fs/2 = {fs_hz / 2:g} Hz, got {item!r}")
    for p in effect.sampled_corners:
        if not params[p] > 1 / (math.pi * fs_hz):
            raise ConfigError(f"{place} {prefix}{p}: must be above 1/(pi fs) = {1 / (math.pi * fs_hz):.3g} s (its corner "
                              f"1/(2 pi tau) below fs/2 = {fs_hz / 2:g} Hz), got {params[p]!r}")


def _check_params(name: str, params: Any, where: str, fs_hz: float | None) -> dict[str, Any]:
    """An override's full parameter set (the defaults, ``params`` over them), every value checked."""
    out = check_table(params, where, CATALOGUE[name].params, key_prefix=f"{name}.")
    _check_against_fs(CATALOGUE[name], out, where, f"{name}.", fs_hz)
    return out


def _override(name: str, value: Any, where: str) -> bool | Mapping[str, Any]:
    """An override as False (off), True (on) or a parameter table; a bare number sets the primary
    parameter (``frame_resonance = -0.2``), as ``--effect NAME=<number>`` does."""
    if isinstance(value, bool) or isinstance(value, Mapping):
        return value
    if isinstance(value, numbers.Real):
        primary = CATALOGUE[name].primary
        if primary is None:
            raise ConfigError(f"{where}: {name} has several parameters; give a table, e.g. "
                              f"{{ {sorted(CATALOGUE[name].params)[0]} = ... }}")
        return {primary: value}
    raise ConfigError(f"{where}: effect {name!r} must be true/false, a number or a table of parameters, "
                      f"got {value!r}")


def resolve_effects(preset_effects: Mapping[str, Mapping[str, Any]],
                    overrides: Mapping[str, Mapping[str, Any] | bool | float] | None = None,
                    where: str = "preset", *, fs_hz: float | None = None,
                    overrides_where: str = "--effect") -> dict[str, dict[str, Any]]:
    """Effects that are on, each with its full parameter set, every value checked against its range
    (and, given ``fs_hz``, frequencies against fs/2).

    ``preset_effects`` is a preset's ``[effects]`` table (``where``: its file); ``overrides`` maps
    a name to False (off), True (on with its parameters), a number (the primary parameter) or a
    parameter table (on, with those parameters changed); ``overrides_where`` names where they
    came from in errors."""
    checked = check_table(preset_effects, where, EFFECTS_SCHEMA, "effects")
    active = {name: checked[name] for name in preset_effects}  # in the preset's order
    for name, params in active.items():
        _check_against_fs(CATALOGUE[name], params, f"{where} [effects.{name}]", "", fs_hz)
    for name, raw in (overrides or {}).items():
        if name not in CATALOGUE:
            raise ConfigError(f"{overrides_where}: unknown effect {name!r}; known: {', '.join(CATALOGUE)}")
        value = _override(name, raw, f"{overrides_where} {name}")
        if value is False:
            active.pop(name, None)
            continue
        base = active.get(name, {}) if value is True else {**active.get(name, {}), **value}
        active[name] = _check_params(name, base, overrides_where, fs_hz)
    return active


def validate_effects(settings: Mapping[str, Any], where: str, *, fs_hz: float | None = None
                     ) -> dict[str, dict[str, Any]]:
    """Check an effect-settings table on its own (the daemon's ``[source] effects``: name -> true,
    false, a number for the primary parameter, or a parameter table) before any rig is built.

    Returns the effects it switches on with their full parameters; a :class:`ConfigError` names
    ``where``, ``EFFECT.param``, the value and its range."""
    if not isinstance(settings, Mapping):
        raise ConfigError(f"{where}: expected a table of effects, got {settings!r}")
    return resolve_effects({}, settings, where, fs_hz=fs_hz, overrides_where=where)


def parse_effect_args(args: Iterable[str]) -> dict[str, Mapping[str, Any] | bool]:
    """``NAME=on|off``, ``NAME=<number>`` (sets the primary parameter) or ``NAME.param=<number>``;
    each number is checked against its range at once (fs/2 when the rig is built)."""
    out: dict[str, Any] = {}
    for arg in args:
        key, sep, raw = arg.partition("=")
        if not sep:
            raise ConfigError(f"--effect {arg!r}: expected NAME=VALUE")
        name, dot, param = key.partition(".")
        if dot and not param:  # not the primary parameter silently: the user meant one and left it out
            raise ConfigError(f"--effect {arg!r}: no parameter name after {name + '.'!r}; "
                              f"use {name}=VALUE or {name}.PARAM=VALUE")
        if name not in CATALOGUE:
            raise ConfigError(f"--effect {arg!r}: unknown effect {name!r}; known: {', '.join(CATALOGUE)}")
        if not param and raw.strip().lower() in _ON | _OFF:
            out[name] = raw.strip().lower() in _ON
            continue
        try:
            value = float(raw)
        except ValueError as err:
            raise ConfigError(f"--effect {arg!r}: {raw!r} is not on/off or a number") from err
        param = param or CATALOGUE[name].primary
        if param is None:
            raise ConfigError(f"--effect {arg!r}: {name} has several parameters; use {name}.PARAM=VALUE")
        spec = CATALOGUE[name].params.get(param)
        if spec is None:
            raise ConfigError(f"--effect {arg!r}: {name} has no parameter {param!r}")
        if spec.kind is list:
            raise ConfigError(f"--effect {arg!r}: {name}.{param} is a list; set it in a rig preset")
        value = check_value(spec, value, "--effect", "", f"{name}.{param}")
        prev = out.get(name)
        out[name] = {**(prev if isinstance(prev, dict) else {}), param: value}
    return out
