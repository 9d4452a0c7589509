"""What the simulation can change, as columns of a linearised fit: the calibration a bench engineer
would do, and each candidate effect switched on.

Each column is how the bench day's features move when one parameter moves, measured by replaying
the day on the simulated rig (:mod:`.forward`) at the baseline and once more with the parameter
moved.  A parameter is expressed in the coordinate in which the features move almost linearly (a
time constant as its inverse, a conductivity as a log factor), so the linearised fit is a good
first answer and re-simulations at the fitted values refine it (Gauss-Newton).

The calibration (stage 1 of the issue), each parameter with a prior from the preset:

- ``instrument.fn_hz`` (prior +-5 %) and ``instrument.zeta_n`` (+-50 %): the load cell, from the
  voice coil's sweep and the force's harmonics;
- ``geometry.airgap_m``, ``depth_m`` and ``middle_tooth_width_m`` (+-20 % each): the force law and
  the flux per ampere of both E-cores (a real core is off its drawing in more than its gap);
- ``magnet.remanence_t`` (+-10 %): the magnet's bias;
- ``voicecoil.force_constant_n_per_a`` (+-50 %): the voice coil's Bl, which the paper does not give;
- ``iron.conductivity_s_per_m`` (+-50 %, when the baseline has ``lamination_eddy_currents``) and
  ``magnet.conductivity_s_per_m`` (+-70 %, with ``magnet_eddy_currents``): the eddy-current lags;
- ``effects.frame_resonance.depth`` (+-0.2, when the baseline has the frame's modes);
- ``gain.flux_Wb`` and ``gain.force_N`` (+-10 %): the integrator's and the charge amplifier's
  sensitivities (one each for the bench);
and the static loop (:mod:`.calibrate`).  A value the data push beyond three prior widths is a
finding of its own.
"""

from __future__ import annotations

import dataclasses
import json
import math
from concurrent.futures import Executor
from dataclasses import dataclass, field
from typing import Any, Callable, Mapping, Sequence

from ...config.effects import CATALOGUE
from ...config.schema import MAX_MAGNITUDE
from ...errors import ConfigError
from .forward import Point, preset_value, replay_features, with_effects, with_value

__all__ = ["Knob", "KNOBS", "Probe", "PROBES", "CATALOGUE_FRAME", "GAINS", "Simulator", "accepts", "catalogue_params", "check_known"]


@dataclass(frozen=True)
class Knob:
    """A preset number calibrated in log space: x = ln(value / preset), prior x ~ N(0, prior_rel^2);
    or, ``linear``, x = value - preset with prior width ``prior_rel`` in the value's unit (a
    parameter that may be 0).  A path ``effects.NAME.PARAM`` is a baseline effect's parameter."""

    path: str
    prior_rel: float
    needs: str | None = None  # the baseline effect without which this knob moves nothing
    linear: bool = False


KNOBS = (
    Knob("instrument.fn_hz", 0.05),
    Knob("instrument.zeta_n", 0.5),
    Knob("geometry.airgap_m", 0.2),
    Knob("geometry.depth_m", 0.2),
    Knob("geometry.middle_tooth_width_m", 0.2),
    Knob("magnet.remanence_t", 0.1),
    Knob("voicecoil.force_constant_n_per_a", 0.5),  # the paper gives no Bl: the preset's is assumed
    Knob("iron.conductivity_s_per_m", 0.5, needs="lamination_eddy_currents"),
    Knob("magnet.conductivity_s_per_m", 0.7, needs="magnet_eddy_currents"),
    Knob("effects.frame_resonance.depth", 0.2, needs="frame_resonance", linear=True),
)
#: Channel sensitivities (x = relative gain error), prior +-10 %.
GAINS = {"gain.flux_Wb": ("flux_Wb", 0.1), "gain.force_N": ("force_N", 0.1)}


@dataclass(frozen=True)
class Probe:
    """One fitted parameter of a candidate effect: the effect's catalogue parameters at coordinate
    ``u`` are ``params(u)``; ``u = probe`` is where its column is measured; ``value(u)`` is the
    catalogue value reported (and ``unit`` its unit), ``lower`` and ``upper`` the bounds on u."""

    effect: str
    param: str
    probe: float
    params: Callable[[float], Mapping[str, Any]]
    value: Callable[[float], float]
    lower: float = -math.inf
    upper: float = math.inf
    #: For an effect far from linear in u (a high-pass's time constant moves the force's DC and its
    #: transients at once): u values to simulate first; the best is refined by a local column.
    grid: tuple[float, ...] = ()
    #: the effect's other parameters while this one is probed (a skew of one channel: the others 0)
    fixed: Mapping[str, Any] = field(default_factory=dict)
    #: the value is 1/u (a time constant, a stiffness): a larger effect is a smaller value
    inverse: bool = False

    @property
    def is_switch(self) -> bool:
        """An effect without a continuous parameter (its strength is the column's scale only)."""
        return self.param == "strength"

    def setting(self, u: float) -> dict[str, Any]:
        """The effect's parameters with this one at u and the others at ``fixed``."""
        return {**self.fixed, **self.params(u)}

    def derivative(self, u: float) -> float:
        """d value / d u, for the standard error of the reported value."""
        h = 1e-6 * max(abs(u), abs(self.probe))
        return (self.value(u + h) - self.value(u - h)) / (2 * h)


def _inverse(effect: str, param: str, probe: float, grid: tuple[float, ...] = ()) -> Probe:
    return Probe(effect, param, probe, lambda u: {param: 1.0 / max(u, 1e-300)}, lambda u: 1.0 / u if u > 0 else math.inf,
                 lower=0.0, grid=tuple(1.0 / g for g in grid), inverse=True)


#: The catalogue's own frame modes (the paper's, at their catalogue frequencies and damping), their
#: depth fitted: what a frame like the paper's is, beside the searched mode of a frame not like it.
CATALOGUE_FRAME = Probe("frame_resonance", "depth", 0.2, lambda u: {"depth": u}, lambda u: u, lower=-1.0)
#: Where a frame mode is looked for (Hz; :mod:`.search`'s band): a linear step beyond it is held at its edge.
FRAME_BAND_HZ = (300.0, 8000.0)


def _in_band(frequency_hz: float) -> float:
    return min(max(frequency_hz, FRAME_BAND_HZ[0]), FRAME_BAND_HZ[1])


#: Time constants (s) simulated first for the high-pass effects: a day's transients to beyond it.
TIME_CONSTANT_GRID = (0.25, 1.0, 4.0, 16.0, 64.0)
#: Relaxation times (s) simulated first: a loss peak (w tau = 1) from 16 Hz to 1.6 kHz.
RELAXATION_GRID = (1e-4, 3e-4, 1e-3, 3e-3, 1e-2)


def _skew(channel: str) -> Probe:
    zero = {"current_A": 0.0, "force_N": 0.0, "flux_Wb": 0.0, "sense_V": 0.0, "command_V": 0.0}
    return Probe("channel_skew", channel, 2e-6, lambda u: {channel: max(u, 0.0)}, lambda u: u, lower=0.0, fixed=zero)


def _linear(effect: str, param: str, probe: float, lower: float = -math.inf, **fixed: Any) -> Probe:
    return Probe(effect, param, probe, lambda u: {param: u}, lambda u: u, lower=lower, fixed=fixed)


def _switch(effect: str) -> Probe:
    """An effect without a continuous parameter of its own: its strength relative to the preset's
    (1 = as the preset or the catalogue describes it)."""
    return Probe(effect, "strength", 1.0, lambda u: {}, lambda u: u, lower=0.0)


#: The candidates' fitted parameters.  Effects measured directly (noise, the ADC's grid) or as
#: lines (mains) are handled elsewhere.
PROBES: Mapping[str, tuple[Probe, ...]] = {
    "charge_amp_highpass": (_inverse("charge_amp_highpass", "time_constant_s", 1.0, TIME_CONSTANT_GRID),),
    "integrator_leak": (_inverse("integrator_leak", "time_constant_s", 1.0, TIME_CONSTANT_GRID),),
    "channel_skew": (_skew("current_A"), _skew("flux_Wb"), _skew("force_N")),
    "force_offset_drift": (_linear("force_offset_drift", "offset_n", 0.1, drift_n_per_s=0.0),
                           _linear("force_offset_drift", "drift_n_per_s", 0.01, offset_n=0.0)),
    "magnet_thermal_drift": (_linear("magnet_thermal_drift", "kelvin_per_s", 0.1),),
    # the iron's loop along the day: linear in the warming at the catalogue's coefficient (a_T dT/dt is what
    # a bench day identifies; its sign too: a loop that widens as it warms is a negative rate here)
    "iron_thermal_drift": (_linear("iron_thermal_drift", "kelvin_per_s", 0.05),),
    "load_cell_compliance": (_inverse("load_cell_compliance", "stiffness_n_per_m", 1e-8),),
    "amplifier_distortion": (_linear("amplifier_distortion", "second", 0.005, third=0.0),
                             _linear("amplifier_distortion", "third", 0.005, second=0.0)),
    # measured around the mode its search found (.search): frequency (a 1 % step), depth, split
    "frame_resonance": (Probe("frame_resonance", "frequency_hz", 0.01, lambda u: {"frequencies_hz": [_in_band(u)]},
                              _in_band, lower=FRAME_BAND_HZ[0], fixed={"zeta": 0.02, "depth": 0.0, "split": 0.0}),
                        _linear("frame_resonance", "depth", 0.05, lower=-0.99),
                        _linear("frame_resonance", "split", 0.005, lower=-0.5)),
    # the excess field is linear in its coefficient (its knee, below the bench's rates, at the catalogue's)
    "excess_loss": (_linear("excess_loss", "coefficient_a_per_m_per_sqrt_t_per_s", 0.3, lower=0.0),),
    # the time constant on a grid (as its inverse; the loss peak w tau = 1 from 16 Hz to 1.6 kHz), the
    # reluctivity it adds (linear) measured there
    # refined only within the grid's span: a shorter tau is, at every frequency the iron is played at,
    # kappa tau dB/dt, the classical eddy field's form (refined to 2 us, it outscored the lamination eddy
    # currents that were there); a longer one a lossless kappa B, a reluctivity
    "magnetic_relaxation": (dataclasses.replace(_inverse("magnetic_relaxation", "time_constant_s", 1e3, RELAXATION_GRID),
                                                lower=1.0 / max(RELAXATION_GRID), upper=1.0 / min(RELAXATION_GRID)),
                            _linear("magnetic_relaxation", "reluctivity_a_per_m_per_t", 40.0, lower=0.0)),
    "static_hysteresis": (_switch("static_hysteresis"),),
    "lamination_eddy_currents": (_switch("lamination_eddy_currents"),),
    "magnet_eddy_currents": (_switch("magnet_eddy_currents"),),
    "iron_saturation": (_switch("iron_saturation"),),
    "instrument_filter": (_switch("instrument_filter"),),
}


class Simulator:
    """The bench day's features as a function of the knobs and the effects: replays on the simulated
    rig, one per rig whose preset changed (a rig's replay is cached by its preset), several at once
    in ``pool`` (a process pool, or None to replay here)."""

    def __init__(self, presets: Mapping[str, Mapping[str, Any]], baseline: Mapping[str, Mapping[str, Mapping[str, Any]]],
                 points: Sequence[Point], pool: Executor | None = None) -> None:
        self.presets = presets  # rig -> checked preset (the nominal)
        self.baseline = baseline  # rig -> effect -> params: the analyst's model of each rig
        self.points = points
        self.pool = pool
        self.replays = 0  # rig replays simulated
        self._cache: dict[str, list] = {}

    def knob_applies(self, knob: Knob) -> bool:
        if knob.path.startswith("effects."):
            _, name, param = knob.path.split(".")
            return any(param in e.get(name, {}) for e in self.baseline.values())
        has = any(_has(p, knob.path) for p in self.presets.values())
        return has and (knob.needs is None or any(knob.needs in e for e in self.baseline.values()))

    def knob_value(self, knob: Knob, x: float = 0.0) -> float:
        """The knob's value at coordinate x (the first rig that has it)."""
        if knob.path.startswith("effects."):
            _, name, param = knob.path.split(".")
            v0 = next(float(e[name][param]) for e in self.baseline.values() if param in e.get(name, {}))
        else:
            v0 = next(preset_value(p, knob.path) for p in self.presets.values() if _has(p, knob.path))
        return v0 + x if knob.linear else v0 * math.exp(x)

    def run(self, knobs: Mapping[str, float] | None = None,
            effects: Mapping[str, Mapping[str, Any]] | None = None) -> list:
        """Features of the replay with knob coordinates ``knobs`` and extra ``effects`` (name ->
        parameters, on top of the baseline; parameters ``None`` switches an effect off)."""
        return self.run_many([(knobs, effects)])[0]

    def run_many(self, requests: Sequence[tuple[Mapping[str, float] | None, Mapping[str, Mapping[str, Any]] | None]]
                 ) -> list[list]:
        """:meth:`run` of several (knobs, effects) at once: the rigs to replay go to the pool together."""
        keyed = [self._presets(knobs, effects) for knobs, effects in requests]
        todo = {key: (rig, preset) for presets in keyed for rig, (key, preset) in presets.items() if key not in self._cache}
        jobs = {key: ((preset, [p for p in self.points if p.rig == rig])) for key, (rig, preset) in todo.items()}
        self.replays += len(jobs)
        if self.pool is not None and len(jobs) > 1:
            futures = {key: self.pool.submit(replay_features, *job) for key, job in jobs.items()}
            self._cache.update({key: fut.result() for key, fut in futures.items()})
        else:
            self._cache.update({key: replay_features(*job) for key, job in jobs.items()})
        out = []
        for presets in keyed:
            by_point: dict[int, Any] = {}
            for rig, (key, _) in presets.items():
                index = [i for i, pt in enumerate(self.points) if pt.rig == rig]
                by_point.update(zip(index, self._cache[key]))
            out.append([by_point[i] for i in range(len(self.points))])
        return out

    def _presets(self, knobs, effects) -> dict[str, tuple[str, dict[str, Any]]]:
        """Per rig, the preset (knobs applied, effects set) and its cache key."""
        out = {}
        linear = {k.path for k in KNOBS if k.linear}
        for rig, preset in self.presets.items():
            p: Mapping[str, Any] = preset
            eff = {name: dict(params) for name, params in self.baseline[rig].items()}
            for path, x in (knobs or {}).items():
                if path.startswith("effects."):
                    _, name, param = path.split(".")
                    if param in eff.get(name, {}):
                        eff[name][param] = float(eff[name][param]) + x if path in linear else eff[name][param] * math.exp(x)
                elif _has(p, path):
                    v0 = preset_value(preset, path)
                    p = with_value(p, path, v0 + x if path in linear else v0 * math.exp(x))
            for name, params in (effects or {}).items():
                if params is None:
                    eff.pop(name, None)
                elif accepts(rig, p, name):
                    eff[name] = {**catalogue_params(preset, name), **eff.get(name, {}), **params}
            # every replay inside the catalogue's ranges: a probe's step from a value on a bound (a
            # calibrated frame depth at its 100) must not be a setting the simulator refuses
            full = with_effects(p, {name: clamp(name, params) for name, params in eff.items()})
            out[rig] = (json.dumps([rig, full], sort_keys=True, default=str), full)
        return out


def clamp(effect: str, params: Mapping[str, Any]) -> dict[str, Any]:
    """``params`` held inside the catalogue's ranges and sizes (a linear step may overshoot a bound the
    simulator refuses; an effect fitted as an inverse and turned off is simulated at 1/1e-300, a
    stiffness of 1e300 N/m, where the largest setting, 1e15, is the same physics)."""
    out = dict(params)
    for k, v in params.items():
        key = CATALOGUE[effect].params.get(k)
        if key is None or not isinstance(v, (int, float)):
            continue
        v = min(max(v, -MAX_MAGNITUDE), MAX_MAGNITUDE)
        if key.ge is not None:
            v = max(v, key.ge)
        if key.gt is not None and v <= key.gt:
            v = key.gt + 1e-12 * max(1.0, abs(key.gt))
        if key.le is not None:
            v = min(v, key.le)
        if key.lt is not None and v >= key.lt:
            v = key.lt - 1e-12 * max(1.0, abs(key.lt))
        out[k] = v
    return out


def _has(preset: Mapping[str, Any], path: str) -> bool:
    node: Any = preset
    for part in path.split("."):
        if not isinstance(node, Mapping) or part not in node:
            return False
        node = node[part]
    return isinstance(node, (int, float)) and not isinstance(node, bool)


def catalogue_params(preset: Mapping[str, Any], name: str) -> dict[str, Any]:
    """The parameters an effect switched on gets: the preset's table if the preset lists it, else
    the catalogue's defaults."""
    return {**dict(CATALOGUE[name].defaults), **dict(preset.get("effects", {}).get(name) or {})}


def accepts(rig: str, preset: Mapping[str, Any], effect: str) -> bool:
    """Whether ``effect`` can act on the rig (its physics: an iron's effects need an E-core, a
    magnet's its magnet); the simulator refuses the rest."""
    magnet = "magnet" in preset
    ecore = preset.get("actuator") == "ecore"
    if effect in ("magnet_eddy_currents", "magnet_thermal_drift"):
        return magnet and ecore
    if effect in ("static_hysteresis", "lamination_eddy_currents", "iron_saturation", "integrator_leak",
                  "load_cell_compliance", "excess_loss", "magnetic_relaxation", "iron_thermal_drift"):
        return ecore
    return True


def check_known(names: Sequence[str], option: str) -> None:
    """A ConfigError naming ``option`` for a name that is not in the catalogue."""
    unknown = [n for n in names if n not in CATALOGUE]
    if unknown:
        raise ConfigError(f"{option}: unknown effect {unknown[0]!r}; known: {', '.join(CATALOGUE)}")
