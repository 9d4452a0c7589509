"""The catalogue of switchable physical effects of the simulated rig.

The names are a public interface: later tools name these effects when they explain why a recording
differs from the simulation.  Every effect is off unless a rig preset lists it (``[effects.NAME]``,
optionally overriding parameters) or the user switches it on (``--effect NAME=on``).
"""

from __future__ import annotations

from dataclasses import dataclass
from types import MappingProxyType
from typing import Any, Iterable, Mapping

from ..errors import ConfigError

__all__ = ["Effect", "CATALOGUE", "resolve_effects", "parse_effect_args"]


@dataclass(frozen=True)
class Effect:
    name: str
    description: str  # one line of physics
    defaults: Mapping[str, Any]
    primary: str | None = None  # the parameter that ``NAME=<number>`` sets


def _e(name: str, description: str, primary: str | None = None, **defaults: Any) -> Effect:
    return Effect(name, description, MappingProxyType(defaults), primary)


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
       "depth", frequencies_hz=[850.0, 1175.0], zeta=0.02, depth=0.2),
    _e("charge_amp_highpass",
       "piezo charge leaks through the charge amplifier's time constant: force high-passed",
       "time_constant_s", time_constant_s=1.0),
    _e("integrator_leak",
       "the flux integrator is lossy (1/(s + 1/tau)): flux high-passed, a phase lead at low f",
       "time_constant_s", time_constant_s=1.0),
    _e("channel_skew",
       "the ADC channels are not sampled at the same instant: per-channel delays in seconds",
       None, current_A=0.0, force_N=2e-6, flux_Wb=1e-6, sense_V=0.0, command_V=0.0),
    _e("force_offset_drift",
       "charge-amplifier output offset and its slow drift (leakage current)",
       "drift_n_per_s", offset_n=0.05, drift_n_per_s=0.01),
    _e("magnet_thermal_drift",
       "magnet remanence falls as the magnet warms: bias force drifts",
       "kelvin_per_s", kelvin_per_s=0.01, remanence_tc_per_k=-0.0012),
    _e("load_cell_compliance",
       "the load cell yields under force, so the airgap closes by F/k",
       "stiffness_n_per_m", stiffness_n_per_m=1.0e9),
    _e("mains_pickup",
       "50 Hz and its 3rd harmonic picked up by the sense leads and the charge amplifier",
       "sense_v", frequency_hz=50.0, sense_v=2e-4, force_n=0.002, third_harmonic=0.3),
    _e("amplifier_distortion",
       "current amplifier's static nonlinearity: 2nd and 3rd harmonics in the coil current",
       "second", second=0.002, third=0.001),
    _e("sensor_noise",
       "white noise on every measured channel (rms values per channel)",
       "force_n", force_n=0.01, current_a=2e-4, flux_wb=2e-8, sense_v=2e-4, command_v=1e-4),
    _e("adc_quantisation",
       "16-bit ADC on every channel: rounding to the LSB of each channel's full scale, clipping",
       None, bits=16, current_a=2.0, force_n=500.0, flux_wb=1e-4, sense_v=1.0, command_v=10.0),
]})

_ON = {"on", "true", "yes", "1"}
_OFF = {"off", "false", "no", "0"}


def _check_params(name: str, params: Mapping[str, Any], where: str) -> dict[str, Any]:
    effect = CATALOGUE[name]
    unknown = set(params) - set(effect.defaults)
    if unknown:
        raise ConfigError(f"{where}: effect {name!r} has no parameter {sorted(unknown)[0]!r}; "
                          f"it has {sorted(effect.defaults) or 'none'}")
    return {**effect.defaults, **params}


def resolve_effects(preset_effects: Mapping[str, Mapping[str, Any]],
                    overrides: Mapping[str, Mapping[str, Any] | bool] | None = None,
                    where: str = "preset") -> dict[str, dict[str, Any]]:
    """Effects that are on, each with its full parameter set.

    ``preset_effects`` is a preset's ``[effects]`` table; ``overrides`` maps a name to False (off),
    True (on with its parameters) or a parameter table (on, with those parameters changed)."""
    active: dict[str, dict[str, Any]] = {}
    for name, params in preset_effects.items():
        if name not in CATALOGUE:
            raise ConfigError(f"{where}: unknown effect {name!r}; known: {', '.join(CATALOGUE)}")
        active[name] = _check_params(name, params or {}, f"{where} [effects.{name}]")
    for name, value in (overrides or {}).items():
        if name not in CATALOGUE:
            raise ConfigError(f"--effect: unknown effect {name!r}; known: {', '.join(CATALOGUE)}")
        if value is False:
            active.pop(name, None)
        elif value is True:
            active.setdefault(name, dict(CATALOGUE[name].defaults))
        else:
            base = active.get(name, dict(CATALOGUE[name].defaults))
            active[name] = _check_params(name, {**base, **value}, f"--effect {name}")
    return active


def parse_effect_args(args: Iterable[str]) -> dict[str, Mapping[str, Any] | bool]:
    """``NAME=on|off``, ``NAME=<number>`` (sets the primary parameter) or ``NAME.param=<number>``."""
    out: dict[str, Any] = {}
    for arg in args:
        key, sep, raw = arg.partition("=")
        if not sep:
            raise ConfigError(f"--effect {arg!r}: expected NAME=VALUE")
        name, _, param = key.partition(".")
        if name not in CATALOGUE:
            raise ConfigError(f"--effect {arg!r}: unknown effect {name!r}; known: {', '.join(CATALOGUE)}")
        if not param and raw.lower() in _ON | _OFF:
            out[name] = raw.lower() in _ON
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
        prev = out.get(name)
        out[name] = {**(prev if isinstance(prev, dict) else {}), param: value}
    return out
