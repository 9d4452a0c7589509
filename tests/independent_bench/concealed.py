"""The independent bench's concealed suite (issue 27), built as issue 13's on ``sim_backend``:
bench days with physics the diagnosis's baseline leaves out, hidden, and null days that hide nothing.

Each :class:`Case` is data: the bench day's effects in this bench's own vocabulary
(:data:`~.bench.BASELINE` plus what is hidden), its seed, the plan played (the whole
:func:`~.bench.bench_day_plan`, or some of its points: a partial sweep), and the bench it is played
on (a :class:`~.bench.BenchConstants` off nominal for a null on another copy of the bench: clocks,
amplifier, geometry a little different, physics no catalogue effect names and a calibration of
airgap, depth and gains should absorb).  ``truth`` (the catalogue names present and absent from the
baseline) and ``expected`` (their parameters, in this bench's units) are the generator's secret: the
recordings' sidecars never carry them.  The diagnosis is handed ``baseline``: the issue's
``static_hysteresis,lamination_eddy_currents,instrument_filter,sensor_noise,adc_quantisation``.

Every hidden effect is at this bench's default strength (``DEFAULTS``) unless its concealment line
says otherwise; each changes the recordings well beyond the noise of a 48-period record
(tests/independent_bench/test_concealed.py measures it).  :func:`write_case` writes a case's day.
:func:`on_another_copy` plays a case on a second copy of the whole bench (every effect's physics and
the constants moved, other seeds: a bench the diagnosis's settings were not chosen on), beyond the
few constants a null's own ``bench`` changes; with a seed, on a copy :func:`drawn_copy` draws at random
(benches nobody chose).

Like the rest of the package, this module imports nothing from ``hystbench``.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Any, Iterator, Mapping

import numpy as np

from .bench import (BASELINE, DEFAULTS, EFFECT_NAMES, VARIANTS, BenchConstants, bench_day_plan, effect_params,
                    write_bench_day)
from .magnetics import ECoreGeometry

__all__ = ["Case", "CASES", "case_hiding", "DIAGNOSIS_BASELINE", "ANOTHER_COPY", "ANOTHER_BENCH", "ANOTHER_SEED", "KEPT_ON_THE_COPY",
           "drawn_copy", "on_another_copy", "day_points", "without_hidden", "write_case"]

#: What the diagnosis is told the bench has (the issue's ``--baseline``), in catalogue names.
DIAGNOSIS_BASELINE: tuple[str, ...] = tuple(BASELINE)

#: write_bench_day's clock: seconds between two points of one rig, and for a rig swap.
PAUSE_S, SWAP_S = 20.0, 300.0

Point = tuple[str, float, float]


@dataclass(frozen=True)
class Case:
    """One bench day of the suite.

    - ``truth``: the catalogue names present in the data and absent from ``baseline`` (empty: a null);
    - ``effects``: this bench's effect table for :func:`~.bench.write_bench_day` (BASELINE plus the
      hidden effects, each ``True`` for the bench's defaults or a dict of overrides);
    - ``seed``: the day's noise and phase seed;
    - ``baseline``: the catalogue names the diagnosis is told of;
    - ``concealment``: one line, how the truth hides;
    - ``expected``: hidden effect -> its full parameter table in this bench's units (for the record);
    - ``plan``: the points played, None for the whole :func:`~.bench.bench_day_plan`;
    - ``bench``: the bench's constants, None for the nominal bench."""

    name: str
    truth: tuple[str, ...]
    effects: dict[str, Any]
    seed: int
    baseline: tuple[str, ...] = DIAGNOSIS_BASELINE
    concealment: str = ""
    expected: dict[str, dict[str, Any]] = field(default_factory=dict)
    plan: tuple[Point, ...] | None = None
    bench: BenchConstants | None = None

    @property
    def null(self) -> bool:
        return not self.truth

    @property
    def hidden(self) -> dict[str, Any]:
        """The effects switched on beyond the baseline's (the truth, in this bench's vocabulary)."""
        return {k: v for k, v in self.effects.items() if k not in BASELINE and v not in (False, None)}

    @property
    def points(self) -> list[Point]:
        return list(self.plan) if self.plan is not None else bench_day_plan()


def _case(name: str, hidden: Mapping[str, Any] | None, *, seed: int, concealment: str,
          plan: list[Point] | None = None, bench: BenchConstants | None = None) -> Case:
    """A case whose truth is exactly what it hides over the baseline (empty: a null)."""
    hidden = dict(hidden or {})
    params = effect_params(hidden)  # checks every name and parameter against the bench's own
    return Case(name=name, truth=tuple(e for e in EFFECT_NAMES if e in params), effects={**BASELINE, **hidden},
                seed=seed, concealment=concealment, expected={e: dict(p) for e, p in params.items()},
                plan=tuple(plan) if plan is not None else None, bench=bench)


def case_hiding(name: str, hidden: Mapping[str, Any], *, seed: int) -> Case:
    """A day of this bench hiding ``hidden`` (this bench's effect table) on the whole plan: what a sweep of
    one effect's size is made of (``python -m benchmarks limits``)."""
    return _case(name, hidden, seed=seed, concealment="a sweep of one effect's size")


def _only(*rigs: str) -> list[Point]:
    return [p for p in bench_day_plan() if p[0] in rigs]


_SKEW_FLUX = {"current_A": 0.0, "flux_Wb": 1.0e-6}

CASES: tuple[Case, ...] = (
    # --- one effect the baseline lacks, at this bench's default strength, on the nominal bench ----------
    _case("magnet_eddy_currents", {"magnet_eddy_currents": True}, seed=2701,
          concealment="the magnet disc as a shorted turn: an extra flux lag growing with f, only on ecore_pm, "
                      "beside the laminations' own"),
    _case("iron_saturation", {"iron_saturation": True}, seed=2702,
          concealment="its own knee (1.05 T, power 8): only ecore_pm reaches 0.89-0.95 T; amplitude-dependent "
                      "harmonics a recalibrated loop half absorbs"),
    _case("frame_resonance", {"frame_resonance": True}, seed=2703,
          concealment="a frame mode at 1175 Hz between the voice coil's 1000 and 1500 Hz points: only +-0.5 % of "
                      "the force there (the weakest default: ~9 noise SE of the period average)"),
    _case("charge_amp_highpass", {"charge_amp_highpass": True}, seed=2704,
          concealment="tau 4 s: force leads by 0.06 deg at 40 Hz, and each record's mean decays since the "
                      "amplifier's reset 0.5 s before it (largest with the magnet's 170 N)"),
    _case("integrator_leak", {"integrator_leak": True}, seed=2705,
          concealment="finite DC gain and a 4.7 MOhm feedback: a flux lead of 0.5 deg at 40 Hz, 0.04 deg at 480 Hz, "
                      "under the iron's hysteresis lag"),
    _case("channel_skew", {"channel_skew": True}, seed=2706,
          concealment="the current sampled 0.5 us late: 0.54 deg at the voice coil's 3 kHz, 0.09 deg at 480 Hz, "
                      "on every pair referenced to current"),
    _case("force_offset_drift", {"force_offset_drift": True}, seed=2707,
          concealment="0.4 mN/s and a 50 mN step settling over 600 s: only along the day's clock"),
    _case("magnet_thermal_drift", {"magnet_thermal_drift": True}, seed=2708,
          concealment="12 K with tau 1500 s at -0.12 %/K: only with the magnet, 2.1-2.4 N less force across "
                      "ecore_pm's block, a slope of 0.3 N over it"),
    _case("load_cell_compliance", {"load_cell_compliance": True}, seed=2709,
          concealment="20 nm/N: the gap closes by 3.4 um under the magnet's 170 N; only in the force's harmonics, "
                      "mostly with the magnet, like a smaller airgap"),
    _case("mains_pickup", {"mains_pickup": True}, seed=2710,
          concealment="50.03 Hz (+30 % third) on force, flux and current: off the harmonics, averaged away by "
                      "whole-period averaging"),
    _case("amplifier_distortion", {"amplifier_distortion": True}, seed=2711,
          concealment="0.4 % second, 1.2 % third order of a 1 A full scale: harmonics in the measured current, "
                      "which the replay is driven by"),
    _case("excess_loss", {"excess_loss": True}, seed=2716,
          concealment="an excess field of 3 A/m at 100 T/s growing as (dB/dt)^0.6 (a power law, not Bertotti's "
                      "square root): a flux lag growing about as f^0.6, beside the laminations' Cauer ladder"),
    _case("magnetic_relaxation", {"magnetic_relaxation": True}, seed=2717,
          concealment="a Cole-Cole relaxation (3 % of the iron's reluctivity, 1.5 ms, alpha 0.85: a spread of "
                      "times, not one): a flux lag peaking near 100 Hz, inside the laminations' own"),
    _case("iron_thermal_drift", {"iron_thermal_drift": True}, seed=2718,
          concealment="the iron warms 25 K with tau 900 s and only its Bouc-Wen loop follows, -0.6 %/K (the "
                      "reluctivity unchanged): 6.0-6.8 % narrower on ecore, 9.1-10.2 % on ecore_pm, mostly an offset "
                      "a loop's calibration absorbs; 0.8-1.1 % along each rig's block"),
    # --- the same effects concealed otherwise --------------------------------------------------------
    _case("magnet_thermal_drift_late", {"magnet_thermal_drift": {"tau_s": 300.0}}, seed=2712,
          concealment="the magnet warmed early (tau 300 s) and has nearly settled when ecore_pm is played late in "
                      "the day: 0.13 N of slope across its block; the rest, 2.7 % less force, looks like a weaker "
                      "magnet (calibration's)"),
    _case("channel_skew_flux", {"channel_skew": _SKEW_FLUX}, seed=2713,
          concealment="the flux sampled 1 us late, the current on time: only the E-cores (40-480 Hz, 0.17 deg at "
                      "480 Hz), a lag growing with f like the laminations' eddy currents"),
    _case("frame_resonance_2400", {"frame_resonance": {"frequency_Hz": 2400.0, "zeta": 0.02}}, seed=2714,
          concealment="a frame mode at 2400 Hz, between the voice coil's 2000 and 3000 Hz points (2-3.5 % of the "
                      "force there), where the load cell's own 4450 Hz mode already bends the response"),
    _case("mains_pickup_60hz_force", {"mains_pickup": {"frequency_Hz": 59.98, "flux_Wb": 0.0, "current_A": 0.0}},
          seed=2715, concealment="a 60 Hz bench's hum on the force channel alone (20 mN): no line on flux or "
                                 "current to corroborate it"),
    # --- two effects on one day -------------------------------------------------------------------------
    _case("force_drift+magnet_drift", {"force_offset_drift": True, "magnet_thermal_drift": True}, seed=2721,
          concealment="two slow force trends along the day's clock; only the magnet's scales with the magnet and "
                      "spares the voice coil and ecore"),
    _case("highpass+current_skew", {"charge_amp_highpass": True, "channel_skew": True}, seed=2722,
          concealment="a force lead ~1/f and a current delay ~f on the same force-vs-current pairs"),
    _case("integrator_leak+distortion", {"integrator_leak": True, "amplifier_distortion": True}, seed=2723,
          concealment="a flux lead at low f and harmonics in the current: both change the E-cores' flux loop"),
    # --- partial sweeps: only some points of the day ---------------------------------------------------
    _case("partial_ecore_pm_integrator_leak", {"integrator_leak": True}, seed=2731, plan=_only("ecore_pm"),
          concealment="ecore_pm alone (10 points): the flux lead under the magnet's eddy lag, no magnetless rig "
                      "to compare with"),
    _case("partial_ecores_current_skew", {"channel_skew": True}, seed=2732, plan=_only("ecore", "ecore_pm"),
          concealment="no voice coil: the 0.5 us current delay only up to 480 Hz (0.09 deg), where it is smallest"),
    # --- nulls: nothing hidden ---------------------------------------------------------------------------
    _case("null_seed1", None, seed=2741, concealment="nothing hidden"),
    _case("null_seed2", None, seed=2742, concealment="nothing hidden"),
    _case("null_bench_clocks", None, seed=2743,
          bench=BenchConstants(adc_clock_ppm=-9.0, generator_clock_ppm=11.0, amp_bandwidth_hz=18e3,
                               amp_gain_a_per_v=0.52),
          concealment="nothing hidden; another copy of the bench: clocks -9/+11 ppm, current amplifier 18 kHz and "
                      "0.52 A/V (the current is measured: calibration's)"),
    _case("null_bench_geometry", None, seed=2744,
          bench=BenchConstants(voice_coil_bl_n_per_a=2.26,
                               ecore=ECoreGeometry(gap_m=0.52e-3, depth_m=24.4e-3)),
          concealment="nothing hidden; another copy of the bench: airgap +4 %, core depth -2.4 %, voice-coil Bl "
                      "+2.7 % (what a calibration of airgap, depth and gains absorbs)"),
)


def _check_suite(cases: tuple[Case, ...]) -> None:
    """Import-time guard: names unique, the truth what is hidden, the baseline without it, plans real."""
    names = [c.name for c in cases]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise ValueError(f"independent concealed suite: case names repeated: {', '.join(dup)}")
    day = set(bench_day_plan())
    for c in cases:
        if set(c.truth) != set(c.hidden) or set(c.truth) & set(c.baseline):
            raise ValueError(f"concealed case {c.name}: truth {c.truth} is not what it hides over {c.baseline}")
        unknown = set(c.baseline) - set(EFFECT_NAMES)
        if unknown:
            raise ValueError(f"concealed case {c.name}: unknown baseline effects {sorted(unknown)}")
        if c.plan is not None and (not c.plan or not set(c.plan) <= day):
            raise ValueError(f"concealed case {c.name}: its plan is not part of the bench day")


_check_suite(CASES)


def day_points(case: Case) -> Iterator[tuple[str, float, float, float]]:
    """(rig, frequency, current, start on the day's clock) of each point of ``case``'s day, the clock
    :func:`~.bench.write_bench_day` keeps (48 periods at 100 kHz, its default pauses)."""
    clock, last = 0.0, None
    for rig, f, ipp in case.points:
        if last is not None:
            clock += SWAP_S if rig != last else PAUSE_S
        yield rig, f, ipp, clock
        clock += int(round(48 * 100e3 / f)) / 100e3
        last = rig


#: Another copy of this bench, for a diagnosis's settings to meet a bench they were not made on: the
#: physics of every effect (the baseline's too) and the bench's constants moved by 7 % to 2.5x from
#: DEFAULTS, as another lab's bench of the same design would be: a softer, narrower Bouc-Wen loop,
#: thinner laminations, a load cell resonance at 3.9 kHz, a frame mode at 900 Hz, 60 Hz mains, more
#: noise, its clocks and amplifier its own.  A case's own overrides still win over these; what the
#: copy keeps is KEPT_ON_THE_COPY.
ANOTHER_COPY: dict[str, dict[str, Any]] = {
    "static_hysteresis": {"a_A_per_m_per_T": 1000.0, "beta_per_T": 11.0, "gamma_per_T": 12.0},
    "lamination_eddy_currents": {"sigma_S_per_m": 2.5e6, "thickness_m": 0.30e-3},
    "magnet_eddy_currents": {"sigma_S_per_m": 8.0e5},
    "iron_saturation": {"knee_T": 0.95, "power": 6.0},
    "instrument_filter": {"fn_Hz": 3900.0, "zeta": 0.02},
    "frame_resonance": {"frequency_Hz": 900.0, "zeta": 0.02},
    "charge_amp_highpass": {"tau_s": 6.0},
    "integrator_leak": {"dc_gain": 5.0e4, "r_feedback_ohm": 10e6},
    "channel_skew": {"current_A": 0.8e-6},
    "force_offset_drift": {"rate_N_per_s": 6e-4},
    "magnet_thermal_drift": {"delta_T_K": 9.0},
    "load_cell_compliance": {"compliance_m_per_N": 3e-8},
    "mains_pickup": {"frequency_Hz": 59.98},
    "amplifier_distortion": {"c2": 0.006, "c3": 0.008},
    "sensor_noise": {"current_A": 1.5e-4, "force_N": 6e-3, "flux_Wb": 6e-9, "command_V": 3e-4},
    "excess_loss": {"field_A_per_m_at_100_T_per_s": 4.0, "exponent": 0.7},
    "magnetic_relaxation": {"share_of_reluctivity": 0.04, "tau_s": 0.8e-3},
    "iron_thermal_drift": {"delta_T_K": 20.0, "loop_per_K": -8e-3},
}
#: What the copy keeps at DEFAULTS, and why: the ADC (a digitiser of the same model), the bench's
#: design choices (laminations stacked, the charge amplifier's low-pass, the amplifier's full scale),
#: and what the concealment lines of the cases state (the frame's coupling, the drifts' time courses,
#: mains amplitudes, which channel is skewed).
KEPT_ON_THE_COPY: dict[str, frozenset[str]] = {
    "lamination_eddy_currents": frozenset({"layers"}), "magnet_eddy_currents": frozenset({"shape_factor"}),
    "instrument_filter": frozenset({"lpf_Hz", "lpf_zeta"}), "frame_resonance": frozenset({"coupling", "mass_ratio"}),
    "charge_amp_highpass": frozenset({"reset_before_s"}), "channel_skew": frozenset({"command_V", "flux_Wb", "force_N"}),
    "force_offset_drift": frozenset({"step_N", "tau_s"}), "magnet_thermal_drift": frozenset({"alpha_per_K", "tau_s"}),
    "mains_pickup": frozenset({"current_A", "flux_Wb", "force_N", "third_harmonic"}),
    "amplifier_distortion": frozenset({"full_scale_A"}), "sensor_noise": frozenset({"flicker_corner_Hz"}),
    "magnetic_relaxation": frozenset({"alpha"}), "iron_thermal_drift": frozenset({"tau_s"}),
    "adc_quantisation": frozenset({"bits", "command_V", "current_A", "flux_Wb", "force_N"}),
}
ANOTHER_BENCH = BenchConstants(adc_clock_ppm=-2.3, generator_clock_ppm=6.2, amp_bandwidth_hz=18e3,
                               voice_coil_bl_n_per_a=2.6,
                               ecore=ECoreGeometry(gap_m=0.55e-3, fringe_extent_m=1.2e-3, iron_mu_r=800.0,
                                                   magnet_hc_a_per_m=8.5e5))
#: Its days' seeds: the nominal case's plus this.
ANOTHER_SEED = 1000


def _own_fields(obj: Any, nominal: Any) -> dict[str, Any]:
    """The fields of a dataclass ``obj`` that differ from ``nominal``'s (a case's own choices)."""
    return {f.name: getattr(obj, f.name) for f in fields(obj) if getattr(obj, f.name) != getattr(nominal, f.name)}


#: A drawn copy's days' seeds: the nominal case's plus this times (the draw + 1).
DRAWN_SEED_STRIDE = 100_000
#: A drawn copy's mains: one of the grids, off it by up to this (Hz).
MAINS_GRIDS_HZ, MAINS_OFF_HZ = (50.0, 60.0), 0.03


def _along(nominal: float, copy: float, u: float) -> float:
    """The point a fraction ``u`` of the way from ``nominal`` to ``copy`` (``-1``: as far the other way):
    in log for quantities of one sign (a conductivity, a time constant, a loop's slope), linearly for
    one that crosses zero (a clock's offset in ppm)."""
    if nominal * copy > 0:
        return float(nominal * (copy / nominal) ** u)
    return float(nominal + u * (copy - nominal))


def drawn_copy(draw: int) -> tuple[dict[str, dict[str, Any]], BenchConstants]:
    """Another copy of the bench drawn at random (``draw`` its seed), for benches nobody chose: each
    effect's physics moved along the line from the bench's defaults to :data:`ANOTHER_COPY` by a
    fraction drawn uniformly in [-1, 1] (one per effect, its parameters together, so that a loop stays
    a loop of one shape family), each constant :data:`ANOTHER_BENCH` moves by its own fraction; the
    mains' grid drawn (50 or 60 Hz, up to 0.03 Hz off).  What the hand-made copy keeps
    (:data:`KEPT_ON_THE_COPY`), this one keeps; the parameters and constants it moves, and how far,
    are the hand-made copy's: 7 % to 2.5x from the defaults, either way.  A seed's bench is fixed by the
    order of the draws (effects by name, then the constants): a key added to ANOTHER_COPY moves every
    drawn bench, and the figures measured on them must be measured again."""
    rng = np.random.default_rng([ANOTHER_SEED, int(draw)])
    params: dict[str, dict[str, Any]] = {}
    for name in sorted(ANOTHER_COPY):
        u = rng.uniform(-1.0, 1.0)
        params[name] = {k: _along(DEFAULTS[name][k], v, u) for k, v in ANOTHER_COPY[name].items()}
    params["mains_pickup"]["frequency_Hz"] = float(rng.choice(MAINS_GRIDS_HZ) + rng.uniform(-MAINS_OFF_HZ, MAINS_OFF_HZ))

    def moved(nominal: Any, copy: Any) -> dict[str, Any]:
        return {f.name: _along(getattr(nominal, f.name), getattr(copy, f.name), rng.uniform(-1.0, 1.0))
                for f in fields(nominal) if f.name != "ecore" and getattr(nominal, f.name) != getattr(copy, f.name)}

    nominal = BenchConstants()
    ecore = replace(nominal.ecore, **moved(nominal.ecore, ANOTHER_BENCH.ecore))
    return params, replace(nominal, ecore=ecore, **moved(nominal, ANOTHER_BENCH))


def on_another_copy(case: Case, draw: int | None = None) -> Case:
    """``case`` played on :data:`ANOTHER_COPY` of the bench (or, with ``draw``, on the copy
    :func:`drawn_copy` draws): each effect it switches on at the copy's parameters under the case's own
    overrides, the copy's constants under the case's own (a null on another copy keeps its clocks or
    geometry), another seed.  The truth is unchanged."""
    copy, another = (ANOTHER_COPY, ANOTHER_BENCH) if draw is None else drawn_copy(draw)
    nominal = BenchConstants()
    bench = another
    if case.bench is not None:
        own = _own_fields(case.bench, nominal)
        if "ecore" in own:
            own["ecore"] = replace(another.ecore, **_own_fields(case.bench.ecore, nominal.ecore))
        bench = replace(another, **own)
    effects = {}
    for name, value in case.effects.items():
        if value is True:
            effects[name] = dict(copy.get(name, {}))
        elif isinstance(value, Mapping):
            if set(value) & set(VARIANTS.get(name, {})):  # another family (an elliptic loop): no copy of it
                raise ValueError(f"case {case.name!r}: {name} as {sorted(VARIANTS[name])} has no parameters on "
                                 "the other copy of the bench")
            effects[name] = {**copy.get(name, {}), **value}
        else:
            effects[name] = value
    params = effect_params(effects)
    seed = case.seed + (ANOTHER_SEED if draw is None else DRAWN_SEED_STRIDE * (int(draw) + 1))
    return replace(case, effects=effects, seed=seed, bench=bench,
                   expected={e: dict(params[e]) for e in case.truth})


def without_hidden(case: Case) -> Case:
    """The same day with nothing hidden: the baseline's effects, same seed, plan and bench."""
    return replace(case, name=f"{case.name}~without", truth=(), expected={},
                   effects={k: v for k, v in case.effects.items() if k in BASELINE})


def write_case(case: Case, folder: str | Path) -> Path:
    """Write ``case``'s bench day into ``folder`` (one folder, every rig of its plan, one clock: a CSV and
    a sidecar per point, the sidecars without the truth); returns the folder."""
    folder = Path(folder)
    write_bench_day(folder, effects=dict(case.effects), seed=case.seed, periods=48, pause_s=PAUSE_S,
                    swap_s=SWAP_S, plan=case.points, bench=case.bench)
    return folder
