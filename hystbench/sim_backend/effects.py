"""The catalogue of switchable physical effects of the simulated rig.

The names are a public interface: later tools name these effects when they explain why a recording
differs from the simulation.  Every effect is off unless a rig preset lists it (``[effects.NAME]``,
optionally overriding parameters) or the user switches it on (``--effect NAME=on``).

Every parameter has a physical range (:class:`Range`): a negative time constant or a frame mode
above the Nyquist frequency would give numbers with no meaning and no error, so a value outside
its range is a :class:`~hystbench.errors.ConfigError` naming ``EFFECT.param``, the value and the
range, wherever it comes from (a rig preset, ``--effect``, the daemon's ``[source] effects``).
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any, Iterable, Mapping

from ..errors import ConfigError

__all__ = ["Effect", "Range", "CATALOGUE", "resolve_effects", "parse_effect_args", "validate_effects"]


@dataclass(frozen=True)
class Range:
    """The values a parameter may take: an interval, optionally also below fs/2 and whole."""

    lo: float = -math.inf
    hi: float = math.inf
    lo_open: bool = True
    hi_open: bool = True
    below_nyquist: bool = False  # also < fs/2 once the sample rate is known
    integer: bool = False

    def __str__(self) -> str:
        lo = "-inf" if self.lo == -math.inf else f"{self.lo:g}"
        hi = "inf" if self.hi == math.inf else f"{self.hi:g}"
        if self.below_nyquist and self.hi == math.inf:
            hi = "fs/2"
        text = f"{'(' if self.lo_open else '['}{lo}, {hi}{')' if self.hi_open or hi == 'fs/2' else ']'}"
        return text + (", whole" if self.integer else "")

    def problem(self, value: Any, fs_hz: float | None = None) -> str | None:
        """Why ``value`` is not in the range (None: it is)."""
        if isinstance(value, bool) or not isinstance(value, numbers.Real):
            return "is not a number"
        v = float(value)
        if not math.isfinite(v):
            return "is not finite"
        if self.integer and v != int(v):
            return "is not a whole number"
        if (v <= self.lo if self.lo_open else v < self.lo) or (v >= self.hi if self.hi_open else v > self.hi):
            return "is out of range"
        if self.below_nyquist and fs_hz is not None and not v < fs_hz / 2:
            return f"is not below fs/2 = {fs_hz / 2:g} Hz"
        return None


_POSITIVE = Range(0.0)
_NONNEGATIVE = Range(0.0, lo_open=False)
_ANY = Range()
_FRACTION = Range(0.0, 1.0, lo_open=False)  # [0, 1)
_FREQUENCY = Range(0.0, below_nyquist=True)


@dataclass(frozen=True)
class Effect:
    name: str
    description: str  # one line of physics
    defaults: Mapping[str, Any]
    primary: str | None = None  # the parameter that ``NAME=<number>`` sets
    ranges: Mapping[str, Range] = field(default_factory=dict)  # one per parameter (a list: each element)


def _e(name: str, description: str, primary: str | None = None, ranges: Mapping[str, Range] | None = None,
       **defaults: Any) -> Effect:
    return Effect(name, description, MappingProxyType(defaults), primary, MappingProxyType(dict(ranges or {})))


_SKEW = Range(0.0, 1e-3, lo_open=False, hi_open=False)  # a delay (the rig cannot lead), up to 1 ms
_DISTORTION = Range(-0.1, 0.1, lo_open=False, hi_open=False)  # per A, per A^2: a monotonic amplifier


CATALOGUE: Mapping[str, Effect] = MappingProxyType({e.name: e for e in [
    _e("static_hysteresis",
       "rate-independent iron hysteresis (Preisach model fitted to the real loops): flux lags current"),
    _e("lamination_eddy_currents",
       "eddy currents in the laminations, H_e = sigma d^2/12 dB/dt: lag growing with frequency"),
    _e("magnet_eddy_currents",
       "eddy currents in a conducting magnet (NdFeB, SmCo) oppose flux change: extra lag"),
    _e("iron_saturation",
       "the iron's single-valued B-H curve bends towards saturation instead of staying linear"),
    _e("instrument_filter",
       "load cell + frame and charge amplifier as two 2nd-order low-passes (paper Figs. 8-9)"),
    _e("frame_resonance",
       "small extra frame modes (paper Fig. 7c peaks near 850 and 1175 Hz)",
       "depth", {"frequencies_hz": _FREQUENCY, "zeta": Range(0.0, 1.0, hi_open=False), "depth": Range(-1.0)},
       frequencies_hz=[850.0, 1175.0], zeta=0.02, depth=0.2),
    _e("charge_amp_highpass",
       "piezo charge leaks through the charge amplifier's time constant: force high-passed",
       "time_constant_s", {"time_constant_s": _POSITIVE}, time_constant_s=1.0),
    _e("integrator_leak",
       "the flux integrator is lossy (1/(s + 1/tau)): flux high-passed, a phase lead at low f",
       "time_constant_s", {"time_constant_s": _POSITIVE}, time_constant_s=1.0),
    _e("channel_skew",
       "the ADC channels are not sampled at the same instant: per-channel delays in seconds",
       None, dict.fromkeys(("current_A", "force_N", "flux_Wb", "sense_V", "command_V"), _SKEW),
       current_A=0.0, force_N=2e-6, flux_Wb=1e-6, sense_V=0.0, command_V=0.0),
    _e("force_offset_drift",
       "charge-amplifier output offset and its slow drift (leakage current)",
       "drift_n_per_s", {"offset_n": _ANY, "drift_n_per_s": _ANY}, offset_n=0.05, drift_n_per_s=0.01),
    _e("magnet_thermal_drift",
       "magnet remanence falls as the magnet warms: bias force drifts",
       "kelvin_per_s", {"kelvin_per_s": _ANY,  # reversible Br coefficient: -0.03 (SmCo) to -0.2 %/K (ferrite)
                        "remanence_tc_per_k": Range(-0.01, 0.0, lo_open=False, hi_open=False)},
       kelvin_per_s=0.01, remanence_tc_per_k=-0.0012),
    _e("load_cell_compliance",
       "the load cell yields under force, so the airgap closes by F/k",
       "stiffness_n_per_m", {"stiffness_n_per_m": _POSITIVE}, stiffness_n_per_m=1.0e9),
    _e("mains_pickup",
       "50 Hz and its 3rd harmonic picked up by the sense leads and the charge amplifier",
       "sense_v", {"frequency_hz": _FREQUENCY, "sense_v": _NONNEGATIVE, "force_n": _NONNEGATIVE,
                   "third_harmonic": _FRACTION},
       frequency_hz=50.0, sense_v=2e-4, force_n=0.002, third_harmonic=0.3),
    _e("amplifier_distortion",
       "current amplifier's static nonlinearity: 2nd and 3rd harmonics in the coil current",
       "second", {"second": _DISTORTION, "third": _DISTORTION}, second=0.002, third=0.001),
    _e("sensor_noise",
       "white noise on every measured channel (rms values per channel)",
       "force_n", dict.fromkeys(("force_n", "current_a", "flux_wb", "sense_v", "command_v"), _NONNEGATIVE),
       force_n=0.01, current_a=2e-4, flux_wb=2e-8, sense_v=2e-4, command_v=1e-4),
    _e("adc_quantisation",
       "16-bit ADC on every channel: rounding to the LSB of each channel's full scale, clipping",
       None, {"bits": Range(2.0, 32.0, lo_open=False, hi_open=False, integer=True),
              **dict.fromkeys(("current_a", "force_n", "flux_wb", "sense_v", "command_v"), _POSITIVE)},
       bits=16, current_a=2.0, force_n=500.0, flux_wb=1e-4, sense_v=1.0, command_v=10.0),
]})

_ON = {"on", "true", "yes"}
_OFF = {"off", "false", "no"}  # not "0"/"1": NAME=0 and NAME=1 are numbers for the primary parameter


def _check_value(name: str, param: str, value: Any, where: str, fs_hz: float | None) -> Any:
    """``value`` if it is in ``name.param``'s range (every element, for a list parameter)."""
    rng = CATALOGUE[name].ranges[param]
    items = value if isinstance(CATALOGUE[name].defaults[param], list) else [value]
    if isinstance(CATALOGUE[name].defaults[param], list) and not isinstance(value, (list, tuple)):
        raise ConfigError(f"{where}: {name}.{param} = {value!r} must be a list of numbers in {rng}")
    for item in items:
        why = rng.problem(item, fs_hz)
        if why is not None:
            raise ConfigError(f"{where}: {name}.{param} = {item!r} {why}; its range is {rng}")
    return list(value) if isinstance(value, (list, tuple)) else value


def _check_params(name: str, params: Mapping[str, Any], where: str, fs_hz: float | None = None) -> dict[str, Any]:
    effect = CATALOGUE[name]
    if not isinstance(params, Mapping):
        raise ConfigError(f"{where}: effect {name!r} takes a table of parameters, got {params!r}")
    unknown = set(params) - set(effect.defaults)
    if unknown:
        raise ConfigError(f"{where}: effect {name!r} has no parameter {sorted(unknown)[0]!r}; "
                          f"it has {sorted(effect.defaults) or 'none'}")
    full = {**effect.defaults, **params}
    return {k: _check_value(name, k, v, where, fs_hz) for k, v in full.items()}


def _override(name: str, value: Any, where: str) -> bool | dict[str, Any]:
    """An override as False (off), True (on) or a parameter table; a bare number sets the primary
    parameter (``frame_resonance = -0.2``), as ``--effect NAME=<number>`` does."""
    if isinstance(value, bool) or isinstance(value, Mapping):
        return value
    if isinstance(value, numbers.Real):
        primary = CATALOGUE[name].primary
        if primary is None:
            raise ConfigError(f"{where}: {name} has several parameters; give a table, e.g. "
                              f"{{ {sorted(CATALOGUE[name].defaults)[0]} = ... }}")
        return {primary: value}
    raise ConfigError(f"{where}: effect {name!r} must be true/false, a number or a table of parameters, "
                      f"got {value!r}")


def resolve_effects(preset_effects: Mapping[str, Mapping[str, Any]],
                    overrides: Mapping[str, Mapping[str, Any] | bool | float] | None = None,
                    where: str = "preset", *, fs_hz: float | None = None,
                    overrides_where: str = "--effect") -> dict[str, dict[str, Any]]:
    """Effects that are on, each with its full parameter set, every value checked against its range
    (and, given ``fs_hz``, frequencies against fs/2).

    ``preset_effects`` is a preset's ``[effects]`` table; ``overrides`` maps a name to False (off),
    True (on with its parameters), a number (the primary parameter) or a parameter table (on, with
    those parameters changed); ``overrides_where`` names where they came from in errors."""
    active: dict[str, dict[str, Any]] = {}
    for name, params in preset_effects.items():
        if name not in CATALOGUE:
            raise ConfigError(f"{where}: unknown effect {name!r}; known: {', '.join(CATALOGUE)}")
        active[name] = _check_params(name, params or {}, f"{where} [effects.{name}]", fs_hz)
    for name, raw in (overrides or {}).items():
        if name not in CATALOGUE:
            raise ConfigError(f"{overrides_where}: unknown effect {name!r}; known: {', '.join(CATALOGUE)}")
        value = _override(name, raw, f"{overrides_where} {name}")
        if value is False:
            active.pop(name, None)
        elif value is True:
            active.setdefault(name, _check_params(name, {}, f"{overrides_where} {name}", fs_hz))
        else:
            base = active.get(name, dict(CATALOGUE[name].defaults))
            active[name] = _check_params(name, {**base, **value}, f"{overrides_where} {name}", fs_hz)
    return active


def validate_effects(settings: Mapping[str, Any], where: str, *, fs_hz: float | None = None
                     ) -> dict[str, dict[str, Any]]:
    """Check an effect-settings table on its own (the daemon's ``[source] effects``: name -> true,
    false, a number for the primary parameter, or a parameter table) before any rig is built.

    Returns the effects it switches on with their full parameters; a :class:`ConfigError` names
    ``where``, the effect, ``EFFECT.param``, the value and its range."""
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
        name, _, param = key.partition(".")
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
        if param not in CATALOGUE[name].defaults:
            raise ConfigError(f"--effect {arg!r}: {name} has no parameter {param!r}")
        if isinstance(CATALOGUE[name].defaults[param], list):
            raise ConfigError(f"--effect {arg!r}: {name}.{param} is a list; set it in a rig preset")
        _check_value(name, param, value, f"--effect {arg!r}", None)
        prev = out.get(name)
        out[name] = {**(prev if isinstance(prev, dict) else {}), param: value}
    return out
