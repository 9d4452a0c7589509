"""The concealed-effect suite of issue 13: bench days with physics the diagnosis's baseline leaves out.

Each :class:`Case` is data: what the generator adds to (or changes in) each rig of a bench day, on the
nominal presets or on a foreign bench (``sim_backend.benches``: another iron, geometry off by up to
20 %, an instrument off its nominal values: physics no catalogue effect names), and the baseline the
diagnosis is given.  ``truth`` (the effects present in the data and absent from the baseline) and
``expected`` (their parameters) are the generator's secret: tests compare the diagnosis's answer with
them; the recordings' sidecars never carry them (``bench_day.public_metadata``).

How each effect is concealed is the issue's list: under another effect of similar signature, below the
noise within any one period, only in the harmonics, only with the magnet, only at one end of the sweep.
Null cases (``truth`` empty) must come out "none": other seeds, presets off nominal within what
calibration absorbs, foreign benches.  :func:`simulate_case` plays one case's bench day.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any, Callable, Iterable, Mapping

from ..config import load_rig
from ..config.effects import CATALOGUE
from ..errors import ConfigError
from ..formats.recording import Recording
from .bench_day import (BENCH_DAY_RIGS, BenchDayPlan, bench_effects, bench_presets, public_metadata, run_rig_block,
                        simulate_bench_day)
from .bench_day import _rig_seed  # the bench day's own seeding: a case off nominal reproduces its day

__all__ = ["Case", "CASES", "PRESET_BASELINE", "DIAGNOSED_DIRECTLY", "make_case", "simulate_case"]

#: The effects of the three rigs' presets together (the voice coil's frame modes, the E-cores' iron, the
#: magnet's eddy currents), in catalogue order: the baseline a case hands over when it leaves one out.
PRESET_BASELINE: tuple[str, ...] = tuple(e for e in CATALOGUE if e in {
    "static_hysteresis", "lamination_eddy_currents", "magnet_eddy_currents", "iron_saturation",
    "instrument_filter", "frame_resonance", "sensor_noise", "adc_quantisation"})

#: Effects no case leaves out of the baseline: the noise and the ADC's grid are measured directly on the
#: samples (rms about the period average; the step between sample values), not named by a model fit.
DIAGNOSED_DIRECTLY: tuple[str, ...] = ("sensor_noise", "adc_quantisation")

#: One load cell, one frame: in a case whose baseline is given explicitly (union of the presets), the
#: frame's modes are on every rig with force, so that the baseline is true of every rig but for the truth.
_ONE_FRAME: Mapping[str, Any] = MappingProxyType({"frame_resonance": {}})

_SKEW_ZERO = {"current_A": 0.0, "force_N": 0.0, "flux_Wb": 0.0, "sense_V": 0.0, "command_V": 0.0}


def _frozen(m: Mapping[str, Mapping[str, Any]]) -> Mapping[str, Mapping[str, Any]]:
    return MappingProxyType({k: MappingProxyType(dict(v)) for k, v in m.items()})


@dataclass(frozen=True)
class Case:
    """One bench day of the suite.

    - ``truth``: the effects present in the data and absent from the baseline (empty: a null case);
    - ``effects``: rig -> effect -> parameters the generator adds or changes (over the rig's preset);
    - ``bench``: a foreign bench's name (``benches.FOREIGN_BENCHES``), None for the nominal presets;
    - ``seed``: the day's noise seed;
    - ``baseline``: the effects the diagnosis is told of, None for the presets' own;
    - ``concealment``: one line, how the truth hides;
    - ``expected``: effect -> catalogue parameter -> the generator's value (for tests; parameterless
      effects of the iron and magnet have an empty table);
    - ``preset_factors``: rig -> ``table.key`` -> factor on the preset value (a bench off nominal within
      what calibration should absorb; no catalogue effect names it)."""

    name: str
    truth: tuple[str, ...]
    effects: Mapping[str, Mapping[str, Mapping[str, Any]]]
    bench: str | None
    seed: int
    baseline: tuple[str, ...] | None
    concealment: str
    expected: Mapping[str, Mapping[str, float]]
    preset_factors: Mapping[str, Mapping[str, float]] = field(default_factory=lambda: MappingProxyType({}))

    @property
    def null(self) -> bool:
        return not self.truth


def make_case(name: str, truth: Iterable[str], bench_wide: Mapping[str, Mapping[str, Any]], *, seed: int,
         concealment: str, bench: str | None = None, leave_out: bool = False,
         preset_factors: Mapping[str, Mapping[str, float]] | None = None) -> Case:
    """A :class:`Case` from a bench-wide effect table (expanded to the rigs each effect acts on, as
    ``bench_day.bench_effects`` does: an instrument's effect on every rig with its channel, the iron's
    on the E-cores, the magnet's on ``ecore_pm``).  ``leave_out``: the truth is already in the presets
    and the baseline (the presets' union, one frame for all rigs) leaves it out."""
    truth = tuple(truth)
    for e in truth:
        if e not in CATALOGUE:
            raise ConfigError(f"concealed case {name}: unknown effect {e!r}")
    table = dict(bench_wide)
    baseline = None
    if leave_out:
        table = {**_ONE_FRAME, **table}
        baseline = tuple(e for e in PRESET_BASELINE if e not in truth)
    expected = {e: {k: float(v) for k, v in {**CATALOGUE[e].defaults, **table.get(e, {})}.items()
                    if not isinstance(v, list)} if e in table else {} for e in truth}
    factors = {r: MappingProxyType(dict(f)) for r, f in (preset_factors or {}).items()}
    return Case(name, truth, _frozen(bench_effects(table)), bench, int(seed), baseline, concealment,
                _frozen(expected), MappingProxyType(factors))


def _skew(**delays: float) -> dict[str, float]:
    return {**_SKEW_ZERO, **delays}


_MAINS_X3 = {  # the catalogue defaults x3
    "frequency_hz": 50.0, "sense_v": 6e-4, "force_n": 6e-3, "third_harmonic": 0.3}
_DRIFT = {"offset_n": 0.0, "drift_n_per_s": 0.02}
_HIGHPASS = {"time_constant_s": 2.0}
_FLUX_SKEW = _skew(flux_Wb=3e-6)

CASES: tuple[Case, ...] = (
    # --- one effect the presets lack, on the nominal bench -------------------------------------------
    make_case("charge_amp_highpass", ["charge_amp_highpass"], {"charge_amp_highpass": _HIGHPASS}, seed=101,
         concealment="a force lead ~1/(f tau) like the instrument's f0/zeta_0 lag with the opposite sign"),
    make_case("charge_amp_highpass_weak", ["charge_amp_highpass"], {"charge_amp_highpass": {"time_constant_s": 20.0}},
         seed=102, concealment="tau 20 s: 0.2 mrad at 40 Hz, below the noise within any one period"),
    make_case("integrator_leak", ["integrator_leak"], {"integrator_leak": {"time_constant_s": 0.5}}, seed=103,
         concealment="a flux lead ~1/(f tau) on the E-cores, under the iron's hysteresis lag"),
    make_case("channel_skew_flux", ["channel_skew"], {"channel_skew": _FLUX_SKEW}, seed=104,
         concealment="a flux delay, phase growing with f like the lamination eddy currents' lag"),
    make_case("channel_skew_current", ["channel_skew"], {"channel_skew": _skew(current_A=2e-6)}, seed=105,
         concealment="the current sampled late: every pair referenced to current shifts by k w 2 us"),
    make_case("force_offset_drift", ["force_offset_drift"], {"force_offset_drift": _DRIFT}, seed=106,
         concealment="no offset at the start, 0.02 N/s: only along the day's clock (one end of the sweep)"),
    make_case("magnet_thermal_drift", ["magnet_thermal_drift"], {"magnet_thermal_drift": {"kelvin_per_s": 0.2}},
         seed=107, concealment="0.2 K/s: only with the magnet, 0.2 mN per period against 30 mN of noise per sample "
                               "(at 0.05 K/s the diagnosis finds 0.049 +- 0.015 K/s, short of a decisive score)"),
    make_case("mains_pickup", ["mains_pickup"], {"mains_pickup": _MAINS_X3}, seed=108,
         concealment="50 and 150 Hz off the harmonics, averaged away by whole-period averaging"),
    make_case("amplifier_distortion", ["amplifier_distortion"],
         {"amplifier_distortion": {"second": 0.01, "third": 0.005}}, seed=109,
         concealment="only in the current's harmonics 2 and 3 against the command"),
    make_case("load_cell_compliance", ["load_cell_compliance"], {"load_cell_compliance": {"stiffness_n_per_m": 1e8}},
         seed=110, concealment="the gap closes by F/k (1.7 um at the magnet's 170 N): only in the force's harmonics, "
                               "mostly with the magnet (at 2e8 N/m found as (2.1 +- 0.6)e8, short of a decisive score)"),
    make_case("frame_resonance", ["frame_resonance"], {}, seed=111, leave_out=True,
         concealment="frame modes at 850/1175 Hz: in the voice coil's sweep and the E-cores' harmonics 2-3"),
    # the iron's rate dependence beyond classical eddy currents (issue 28): catalogue defaults
    make_case("excess_loss", ["excess_loss"], {"excess_loss": {}}, seed=117,
         concealment="a flux lag growing as sqrt(f) on both E-cores (falling as B^-0.5 with amplitude), "
                     "beside the lamination's eddy lag that grows as f"),
    make_case("magnetic_relaxation", ["magnetic_relaxation"], {"magnetic_relaxation": {}}, seed=118,
         concealment="a flux lag peaking at 159 Hz (tau 1 ms) on both E-cores, inside the lamination's eddy lag"),
    make_case("iron_thermal_drift", ["iron_thermal_drift"], {"iron_thermal_drift": {"kelvin_per_s": 2.0}}, seed=119,
         concealment="the iron's static field falls 1 %/s (2 K/s at -0.5 %/K) on each E-core's own clock: a "
                     "hysteresis lag shrinking along the rig's block, read in frequency order like an eddy lag"),
    # --- the baseline leaves out an effect of the presets -------------------------------------------
    make_case("magnet_eddy_currents", ["magnet_eddy_currents"], {}, seed=112, leave_out=True,
         concealment="an extra flux lag growing with f, only with the magnet"),
    make_case("lamination_eddy_currents", ["lamination_eddy_currents"], {}, seed=113, leave_out=True,
         concealment="a flux lag growing with f on both E-cores, under the magnet's eddy currents"),
    make_case("static_hysteresis", ["static_hysteresis"], {}, seed=114, leave_out=True,
         concealment="a rate-independent loop, below the noise within a period at 0.7 A-pp"),
    make_case("iron_saturation", ["iron_saturation"], {}, seed=115, leave_out=True,
         concealment="the permeability falls only at 1.4 A-pp with the magnet: odd and even harmonics"),
    make_case("instrument_filter", ["instrument_filter"], {}, seed=116, leave_out=True,
         concealment="the load cell's resonance: plain in the voice coil's sweep, flat in the E-cores' band"),
    # --- two effects at once -------------------------------------------------------------------------
    make_case("highpass+flux_skew", ["charge_amp_highpass", "channel_skew"],
         {"charge_amp_highpass": _HIGHPASS, "channel_skew": _FLUX_SKEW}, seed=121,
         concealment="a force lead and a flux delay on the same pairs"),
    make_case("drift+mains", ["force_offset_drift", "mains_pickup"],
         {"force_offset_drift": _DRIFT, "mains_pickup": _MAINS_X3}, seed=122,
         concealment="a slow force trend and a 50 Hz line, both off the excitation's harmonics"),
    # --- nulls: nothing left out ---------------------------------------------------------------------
    make_case("null_seed1", [], {}, seed=1, concealment="nothing left out"),
    make_case("null_seed2", [], {}, seed=2, concealment="nothing left out"),
    make_case("null_seed3", [], {}, seed=3, concealment="nothing left out"),
    make_case("null_off_nominal", [], {}, seed=4,
         concealment="nothing left out; load cell fn 3 % high, magnet conductivity x1.5 (calibration's job)",
         preset_factors={"voicecoil_ferrite": {"instrument.fn_hz": 1.03},
                         "ecore": {"instrument.fn_hz": 1.03},
                         "ecore_pm": {"instrument.fn_hz": 1.03, "magnet.conductivity_s_per_m": 1.5}}),
    # --- foreign benches: physics no catalogue effect names ------------------------------------------
    make_case("foreign_m130", [], {}, seed=31, bench="ecore_pm~m130",
         concealment="nothing left out; another iron (M130-27S), geometry and instrument off"),
    make_case("foreign_elliptic", [], {}, seed=32, bench="ecore_pm~elliptic",
         concealment="nothing left out; an elliptic-loop iron (complex permeability), geometry off"),
    make_case("foreign_rayleigh", [], {}, seed=33, bench="ecore_pm~rayleigh",
         concealment="nothing left out; a Rayleigh iron, geometry off"),
    make_case("foreign_elliptic_highpass", ["charge_amp_highpass"], {"charge_amp_highpass": _HIGHPASS}, seed=34,
         bench="ecore_pm~elliptic", concealment="a force lead on a bench whose iron loops are elliptic"),
    make_case("foreign_m130_flux_skew", ["channel_skew"], {"channel_skew": _FLUX_SKEW}, seed=35, bench="ecore_pm~m130",
         concealment="a flux delay on a bench with another iron's eddy-current lag"),
    make_case("foreign_rayleigh_drift", ["force_offset_drift"], {"force_offset_drift": _DRIFT}, seed=36,
         bench="ecore_pm~rayleigh", concealment="a slow force drift on a bench with a Rayleigh iron"),
)


def _check_suite(cases: tuple[Case, ...]) -> None:
    """Import-time guard: names unique, every rig a bench-day rig."""
    names = [c.name for c in cases]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise ConfigError(f"concealed suite: case names repeated: {', '.join(dup)}")
    for c in cases:
        odd = set(c.effects) | set(c.preset_factors)
        if not odd <= set(BENCH_DAY_RIGS):
            raise ConfigError(f"concealed case {c.name}: rigs {sorted(odd - set(BENCH_DAY_RIGS))} not on a bench day")


_check_suite(CASES)


def _scaled(preset: str | Mapping[str, Any], factors: Mapping[str, float], where: str) -> dict[str, Any]:
    """``preset`` with each ``table.key`` multiplied by its factor, checked again."""
    p = copy.deepcopy({k: v for k, v in load_rig(preset).items() if k != "_source"})
    for dotted, factor in factors.items():
        table, _, key = dotted.partition(".")
        if key not in p.get(table, {}):
            raise ConfigError(f"{where}: preset has no {dotted}")
        p[table][key] = p[table][key] * factor
    p["_source"] = f"{where} (preset off nominal: {', '.join(f'{k} x{v:g}' for k, v in factors.items())})"
    return load_rig(p)


def simulate_case(c: Case, tick: Callable[[], None] | None = None, *,
                  plan: BenchDayPlan | None = None) -> list[Recording]:
    """The recordings of case ``c``'s bench day (the issue's day, or ``plan``), in the order recorded,
    their sidecars without the generator's truth."""
    plan = plan or BenchDayPlan()
    effects = {r: {k: dict(v) for k, v in e.items()} for r, e in c.effects.items() if r in plan.rigs}
    if not c.preset_factors:
        return simulate_bench_day(plan, seed=c.seed, effects=effects, bench=c.bench, tick=tick)
    # A preset off nominal is no named bench: the same day as simulate_bench_day, rig by rig, on the
    # scaled presets (simulate_bench_day takes a bench's name only).
    presets = bench_presets(c.bench, plan.rigs)
    for rig, factors in c.preset_factors.items():
        if rig in presets:
            presets[rig] = _scaled(presets[rig], factors, f"concealed case {c.name} rig {rig}")
    recs: list[Recording] = []
    clock = 0.0
    for k, block in enumerate(plan.blocks):
        clock += plan.gap_s if k else 0.0
        part, clock = run_rig_block(presets[block.rig], block, start_s=clock, seed=_rig_seed(c.seed, k),
                                    effects=effects.get(block.rig), settle=plan.settle_s, tick=tick)
        recs += part
    for r in recs:
        r.metadata = public_metadata(r.metadata)
    return recs

