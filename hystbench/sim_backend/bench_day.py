"""A bench day of the simulated rig: the rigs of one bench recorded one after another, as on a bench.

On a real bench the rig keeps running between operating points (the generator is re-set, the
bench settles, the recorder starts), the rigs are swapped with a pause, and one charge amplifier,
one flux integrator, one ADC and the mains serve them all.  So here: ONE running
:class:`~.rig.SimulatedRig` per rig (``set_excitation`` per point, a few periods read and discarded
to settle, then the recording), and each recording's sidecar says when it started on the day's clock
(``start_time_s``): the instruments run on that clock (``SimulatedRig.clock_offset_s``), so a slow
effect of the instrument (``force_offset_drift``, the mains' phase) runs on across the rigs, as the
one charge amplifier's would.  The magnet's warming (``magnet_thermal_drift``) stays on its own rig's
clock: it warms while its rig is driven.

The sidecars of a bench day hold what a real bench's hold: not the generator's truth (``effects``,
``seed``, the generator's true frequency; :func:`public_metadata`), which a diagnosis must never read.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Callable, Iterable, Mapping

import numpy as np

from ..blocks import BlockFlags, SampleBlock, concatenate
from ..config import load_rig
from ..config.effects import CATALOGUE
from ..errors import ConfigError
from ..formats.recording import Recording
from .actuators import ACTUATORS
from .benches import foreign_preset, voice_coil_on_load_cell
from .rig import DEFAULT_FS_HZ, SimulatedRig

__all__ = ["RigBlock", "BenchDayPlan", "BENCH_DAY_RIGS", "TRUTH_KEYS", "E_CORE_FREQS_HZ", "SETTLE_PERIODS",
           "SETTLE_MIN_S", "default_settle_s", "simulate_bench_day", "run_rig_block", "bench_effects",
           "bench_presets", "public_metadata"]

#: The rigs of one bench, in the order a bench day records them (the issue's plan).
BENCH_DAY_RIGS = ("voicecoil_ferrite", "ecore", "ecore_pm")
#: Sidecar keys only the generator knows; a real bench's recordings do not carry them.
TRUTH_KEYS = ("effects", "seed", "generator_frequency_Hz")
_CHUNK = 50_000  # samples per read: the rig's output does not depend on how it is cut
#: Before each recording the rig settles this many periods, and at least SETTLE_MIN_S (the instrument's
#: ring-down and the iron's memory: what the live estimator skips after a change).
SETTLE_PERIODS = 5.0
SETTLE_MIN_S = 0.02


def default_settle_s(frequency_hz: float) -> float:
    """The settling before a recording at ``frequency_hz``: SETTLE_PERIODS periods, at least SETTLE_MIN_S."""
    return max(SETTLE_PERIODS / frequency_hz, SETTLE_MIN_S)


@dataclass(frozen=True)
class RigBlock:
    """One rig's part of a bench day: its operating points (frequency Hz, current A-pp) in the order
    played, each recorded for ``max(periods / f, min_duration_s)`` at ``fs_hz``."""

    rig: str
    points: tuple[tuple[float, float], ...]
    periods: float = 48.0
    min_duration_s: float = 0.0
    fs_hz: float = DEFAULT_FS_HZ

    @classmethod
    def grid(cls, rig: str, freqs_hz: Iterable[float], currents_pp_a: Iterable[float], **kw: Any) -> RigBlock:
        """Every frequency at each current, current by current (a bench engineer's order)."""
        freqs = tuple(float(f) for f in freqs_hz)
        return cls(rig, tuple((f, float(i)) for i in currents_pp_a for f in freqs), **kw)

    def samples(self, frequency_hz: float) -> int:
        """Samples recorded at ``frequency_hz``: at least one."""
        return max(1, round(max(self.periods / frequency_hz, self.min_duration_s) * self.fs_hz))

    def check(self) -> None:
        where = f"bench day: rig {self.rig}"
        if not self.points:
            raise ConfigError(f"{where}: no operating points")
        if not (math.isfinite(self.fs_hz) and self.fs_hz > 0):
            raise ConfigError(f"{where}: fs_hz must be a finite number of Hz > 0, got {self.fs_hz}")
        if not (math.isfinite(self.periods) and self.periods >= 0 and math.isfinite(self.min_duration_s)
                and self.min_duration_s >= 0 and (self.periods > 0 or self.min_duration_s > 0)):
            raise ConfigError(f"{where}: periods ({self.periods}) and min_duration_s ({self.min_duration_s}) must "
                              "be finite, >= 0 and not both 0")
        for f, ipp in self.points:
            if not 0 < f < self.fs_hz / 2:  # also NaN
                raise ConfigError(f"{where}: frequency {f} Hz must be in (0, fs/2 = {self.fs_hz / 2:g} Hz)")
            if not (math.isfinite(ipp) and ipp >= 0):
                raise ConfigError(f"{where}: current {ipp} A-pp must be a finite number >= 0")


def _voice_coil_freqs() -> tuple[float, ...]:
    """12 log-spaced points 10 Hz - 4 kHz, to 3 significant digits (readable file names)."""
    return tuple(float(f"{f:.3g}") for f in np.geomspace(10.0, 4000.0, 12))


#: The E-cores' frequencies on a bench day (the paper's 40-480 Hz).
E_CORE_FREQS_HZ = (40.0, 80.0, 160.0, 320.0, 480.0)


def _default_blocks() -> tuple[RigBlock, ...]:
    return (RigBlock.grid("voicecoil_ferrite", _voice_coil_freqs(), [1.0], periods=20.0, min_duration_s=0.02),
            RigBlock.grid("ecore", E_CORE_FREQS_HZ, [1.27]),
            RigBlock.grid("ecore_pm", E_CORE_FREQS_HZ, [0.7, 1.4]))


@dataclass(frozen=True)
class BenchDayPlan:
    """What a bench day records, rig block by rig block; the defaults are issue 13's day: the voice
    coil's stepped sine (12 points 10 Hz - 4 kHz, 1 A-pp, 20 periods or 20 ms), then ``ecore`` at
    1.27 A-pp and ``ecore_pm`` at 0.7 and 1.4 A-pp at 40-480 Hz, 48 periods each, all at 100 kS/s.
    Before each recording the rig settles ``max(settle_periods / f, settle_min_s)``; the rigs are
    swapped in ``gap_s``."""

    blocks: tuple[RigBlock, ...] = field(default_factory=_default_blocks)
    settle_periods: float = SETTLE_PERIODS
    settle_min_s: float = SETTLE_MIN_S
    gap_s: float = 1.0

    def __post_init__(self) -> None:
        rigs = [b.rig for b in self.blocks]
        if not rigs:
            raise ConfigError("bench day: the plan has no rig blocks")
        if len(set(rigs)) < len(rigs):
            raise ConfigError(f"bench day: each rig runs once (one block per rig), got {', '.join(rigs)}")
        for b in self.blocks:
            b.check()
        for name, v in (("settle_periods", self.settle_periods), ("settle_min_s", self.settle_min_s),
                        ("gap_s", self.gap_s)):
            if not (math.isfinite(v) and v >= 0):
                raise ConfigError(f"bench day: {name} must be a finite number >= 0, got {v}")

    @classmethod
    def quick(cls) -> BenchDayPlan:
        """A short day for a first look and the demo: 4 voice-coil points, 2 frequencies per E-core
        point set, 12 periods."""
        return cls((RigBlock.grid("voicecoil_ferrite", (20.0, 200.0, 1000.0, 4000.0), [1.0], periods=12.0,
                                  min_duration_s=0.02),
                    RigBlock.grid("ecore", (80.0, 320.0), [1.27], periods=12.0),
                    RigBlock.grid("ecore_pm", (80.0, 320.0), [0.7, 1.4], periods=12.0)))

    def settle_s(self, frequency_hz: float) -> float:
        return max(self.settle_periods / frequency_hz, self.settle_min_s)

    @property
    def rigs(self) -> tuple[str, ...]:
        return tuple(b.rig for b in self.blocks)


def public_metadata(meta: Mapping[str, Any]) -> dict[str, Any]:
    """The sidecar without what only the generator knows (:data:`TRUTH_KEYS`)."""
    return {k: v for k, v in meta.items() if k not in TRUTH_KEYS}


def bench_presets(bench: str | None, rigs: Iterable[str] = BENCH_DAY_RIGS) -> dict[str, str | dict[str, Any]]:
    """Each rig of a bench day's preset: the nominal preset's name (``bench`` None), or the foreign
    bench ``bench``'s: both E-cores from its one core (one iron, geometry, coil, instrument; the
    magnet in or out), the ferrite voice coil on its load cell and charge amplifier."""
    rigs = list(rigs)
    if bench is None:
        return {r: r for r in rigs}
    odd = [r for r in rigs if r not in BENCH_DAY_RIGS]
    if odd:
        raise ConfigError(f"bench day on foreign bench {bench}: no rig {', '.join(odd)} on it "
                          f"(it has {', '.join(BENCH_DAY_RIGS)})")
    out: dict[str, str | dict[str, Any]] = {}
    for r in rigs:
        out[r] = voice_coil_on_load_cell(foreign_preset(bench)) if r == "voicecoil_ferrite" else foreign_preset(bench, r)
    return out


#: Effects of the bench's instruments -> the channels they act on (a rig with none of them is left out).
_CHANNEL_EFFECTS: Mapping[str, frozenset[str]] = {
    "instrument_filter": frozenset({"force_N"}), "frame_resonance": frozenset({"force_N"}),
    "charge_amp_highpass": frozenset({"force_N"}), "force_offset_drift": frozenset({"force_N"}),
    "mains_pickup": frozenset({"force_N", "sense_V"}), "integrator_leak": frozenset({"flux_Wb"}),
    "sensor_noise": frozenset({"current_A"}), "adc_quantisation": frozenset({"current_A"}),
    "amplifier_distortion": frozenset({"current_A"}),  # every rig has its current measured
}
_IRON_EFFECTS = frozenset({"static_hysteresis", "lamination_eddy_currents", "iron_saturation", "excess_loss",
                           "magnetic_relaxation", "iron_thermal_drift"})
_MAGNET_EFFECTS = frozenset({"magnet_eddy_currents", "magnet_thermal_drift"})  # the E-core's magnet


def _rig_channels(preset: Mapping[str, Any]) -> set[str]:
    kind = ACTUATORS[preset["actuator"]]
    return {"current_A", "command_V"} | ({"force_N"} if kind.has_force else set()) | (
        {"flux_Wb", "sense_V"} if kind.has_flux else set())


def acts_on(name: str, value: Any, preset: Mapping[str, Any]) -> bool:
    """Whether effect ``name`` (its table ``value``) acts on the rig ``preset``: the iron's on a rig
    with iron, the magnet's on one with a magnet, an instrument's where its channel is."""
    channels = _rig_channels(preset)
    if name in _IRON_EFFECTS:
        return "iron" in preset
    if name == "load_cell_compliance":  # the load cell yields: the E-core's airgap closes
        return "iron" in preset and "force_N" in channels
    if name in _MAGNET_EFFECTS:
        return "magnet" in preset
    if name == "channel_skew":
        return not isinstance(value, Mapping) or bool(channels & set(value))
    return bool(channels & _CHANNEL_EFFECTS[name])


def refuse_effects_not_acting(rig: str, effects: Mapping[str, Any], option: str = "--effect") -> None:
    """A ConfigError naming ``option`` for an effect switched on that does not act on ``rig``: its
    sidecar listed the effect and the samples were those without it (``simulate --rig
    voicecoil_ferrite --effect iron_saturation=on``)."""
    preset = load_rig(rig)
    idle = [n for n, v in effects.items() if v is not False and not acts_on(n, v, preset)]
    if idle:
        raise ConfigError(f"{option}: {', '.join(idle)} does not act on {rig} (the iron's effects need iron, the "
                          "magnet's a magnet, an instrument's its channel); the recording would list it and hold "
                          "none of it")


def bench_effects(effects: Mapping[str, Any], rigs: Iterable[str] = BENCH_DAY_RIGS) -> dict[str, dict[str, Any]]:
    """A bench-wide effect table expanded to per-rig tables (``simulate_bench_day``'s ``effects``):
    each effect goes to the rigs it acts on: an instrument's effect to every rig with the channel it
    concerns (force, flux, sense, current; ``channel_skew`` by the channels its table names), the
    iron's to the E-cores, the magnet's to ``ecore_pm``.  Values as ``SimulatedRig(effects=)`` takes
    them (a table, True, False, a number); every rig is a key (maybe with an empty table)."""
    rigs = list(rigs)
    presets = {r: load_rig(r) for r in rigs}
    out: dict[str, dict[str, Any]] = {r: {} for r in rigs}
    for name, value in effects.items():
        if name not in CATALOGUE:
            raise ConfigError(f"bench effects: unknown effect {name!r}; known: {', '.join(CATALOGUE)}")
        for r in rigs:
            if acts_on(name, value, presets[r]):
                out[r][name] = value
    return out


def _read(rig: SimulatedRig, n: int) -> SampleBlock:
    return concatenate([rig.read(min(_CHUNK, n - k)) for k in range(0, n, _CHUNK)])


def run_rig_block(preset: str | Mapping[str, Any], block: RigBlock, *, start_s: float = 0.0, seed: int = 0,
                  effects: Mapping[str, Any] | None = None, settle: Callable[[float], float] | None = None,
                  tick: Callable[[], None] | None = None) -> tuple[list[Recording], float]:
    """One running rig through ``block``'s points: construct it once (its warm-up is the first point's
    settling), then per point ``set_excitation``, settle (read and discard ``settle(f)`` seconds;
    default 5 periods, at least 20 ms) and record.  The rig's first sample (of its warm-up) is at
    ``start_s`` on the day's clock.  Returns the recordings (the generator's full sidecar, with
    ``start_time_s``; ``clipped: true`` where the ADC clipped) and the day's clock after the last sample."""
    settle = settle or default_settle_s
    f0, i0 = block.points[0]
    warm_s = settle(f0)
    # what SimulatedRig reads before its sample 0 (an endless settling: the rig refuses it, naming f)
    warm_n = math.ceil(warm_s * block.fs_hz) if math.isfinite(warm_s * block.fs_hz) else 0
    offset = start_s + warm_n / block.fs_hz
    rig = SimulatedRig(preset, fs_hz=block.fs_hz, seed=seed, effects=effects, frequency_hz=f0, current_pp_a=i0,
                       warmup_s=warm_s, clock_offset_s=offset)
    recs, end = [], 0
    for k, (f, ipp) in enumerate(block.points):
        if k:
            rig.set_excitation(f, ipp)
            _read(rig, max(1, round(settle(f) * block.fs_hz)))
        samples = _read(rig, block.samples(f))
        meta = {**rig.metadata(), "start_time_s": offset + samples.first_index / block.fs_hz}
        if samples.flags & BlockFlags.CLIP:
            meta["clipped"] = True
        recs.append(Recording(None, rig.fs_hz, dict(samples.channels), meta))
        end = samples.end_index
        if tick is not None:
            tick()
    return recs, offset + end / block.fs_hz


def _rig_seed(seed: int, k: int) -> int:
    """Rig ``k``'s noise seed: distinct per rig and per day, reproducible."""
    return int(np.random.SeedSequence([int(seed), k]).generate_state(1)[0])


def simulate_bench_day(plan: BenchDayPlan | None = None, *, seed: int = 0,
                       effects: Mapping[str, Mapping[str, Any]] | None = None, bench: str | None = None,
                       truth_in_sidecar: bool = False, tick: Callable[[], None] | None = None) -> list[Recording]:
    """The recordings of one bench day, in the order recorded (``start_time_s`` increasing).

    ``plan``: what is recorded (default: issue 13's day, :class:`BenchDayPlan`).  ``effects``: per rig
    (a key of the plan's rigs), overrides merged over the preset's effects as ``SimulatedRig(effects=)``
    merges them (False switches one off); :func:`bench_effects` expands a bench-wide table.
    ``bench``: None for the nominal presets, else a foreign bench (``benches.FOREIGN_BENCHES``), whose
    two E-cores share one core.  Sidecars hold the generator's truth only with ``truth_in_sidecar``.
    ``tick()`` after each recording."""
    plan = plan or BenchDayPlan()
    effects = dict(effects or {})
    odd = sorted(set(effects) - set(plan.rigs))
    if odd:
        raise ConfigError(f"bench day: effects for rig {', '.join(odd)}, which the plan does not record "
                          f"(it records {', '.join(plan.rigs)})")
    presets = bench_presets(bench, plan.rigs)
    recs: list[Recording] = []
    clock = 0.0
    for k, block in enumerate(plan.blocks):
        if k:
            clock += plan.gap_s
        part, clock = run_rig_block(presets[block.rig], block, start_s=clock, seed=_rig_seed(seed, k),
                                    effects=effects.get(block.rig), settle=plan.settle_s, tick=tick)
        recs += part
    if not truth_in_sidecar:
        for r in recs:
            r.metadata = public_metadata(r.metadata)
    return recs
