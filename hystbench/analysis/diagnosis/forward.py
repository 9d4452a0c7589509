"""The simulation a diagnosis compares with: the bench day replayed on the simulated rig.

A candidate effect is judged by switching it on in the same simulator that made the presets, not in
a second, simplified model of it: what the catalogue means by an effect is what the rig does with
it.  The replay follows the recordings' own clock (``start_time_s``): one running rig per rig type,
each point excited as the bench was, the time between points run through, so slow effects (a
charge amplifier's drift, a magnet warming, a high-pass's transient after a change of operating
point) are where the recording has them.  It is noiseless (no sensor noise, ADC or mains: those are
measured directly) and keeps only ``periods`` periods in the middle of each recording, which is
what the features of a noiseless periodic record need.
"""

from __future__ import annotations

import copy
import dataclasses
import math
from dataclasses import dataclass
from typing import Any, Mapping, Sequence

import numpy as np

from ...config import load_rig
from ...config.effects import CATALOGUE
from ...errors import SimulationError
from ...formats.recording import Recording
from ...sim_backend.bench_day import default_settle_s
from ...sim_backend.rig import SimulatedRig
from ..method import recording_name
from .features import RecordFeatures, record_features

__all__ = ["Point", "Replayed", "points_of", "clock_follows_frequency", "replay", "replay_rig", "record_mean", "replayed_features", "replay_features", "MEASURED_DIRECTLY", "with_effects", "with_value", "preset_value"]

#: Effects the replay leaves out: they add no periodic signal (noise, the ADC's grid) or one the
#: features see as non-harmonic lines (mains), and are measured from the recording directly.
MEASURED_DIRECTLY = ("sensor_noise", "adc_quantisation", "mains_pickup")


@dataclass(frozen=True)
class Point:
    """What the replay needs of one recording: the rig, the excitation and when it was recorded."""

    name: str
    rig: str
    frequency_hz: float
    current_pp_a: float
    start_time_s: float
    duration_s: float
    fs_hz: float
    averaged_s: float = math.nan  # the whole periods a feature's DC is the mean of (from the record's start)


def points_of(recordings: Sequence[Recording], averaged_s: Sequence[float] | None = None,
              measured_pp_a: Sequence[float] | None = None) -> tuple[list[Point], bool]:
    """The recordings' points, and whether their sidecars gave the clock.  Without ``start_time_s``
    the recordings are taken as recorded back to back in the order given (the replay then has no
    slow effect to compare).  ``averaged_s``: per recording, the span of whole periods its features'
    DC is the mean of (``periods / frequency_hz`` of its features).  ``measured_pp_a``: per recording,
    the current it really had (twice its fundamental's amplitude), which the replay drives instead of
    the sidecar's setpoint: a real amplifier's bandwidth and gain are not its setpoint's."""
    clocked = all(r.start_time_s is not None for r in recordings)
    points, t = [], 0.0
    for n, rec in enumerate(recordings):
        start = float(rec.start_time_s) if clocked else t
        ipp = rec.current_pp_a if measured_pp_a is None else float(measured_pp_a[n])
        points.append(Point(recording_name(rec), rec.rig, rec.frequency_hz, ipp, start, rec.duration_s,
                            rec.fs_hz, math.nan if averaged_s is None else float(averaged_s[n])))
        t = start + rec.duration_s
    return points, clocked


def clock_follows_frequency(recordings: Sequence[Recording]) -> bool:
    """Whether every block of the day that records flux (a rig at one current, three frequencies or more)
    was played in the order of its frequencies, up or down.  Why it matters: the baseline's iron discrepancy
    is smooth in frequency per block, so there a slow change along the day's clock (a magnet or iron
    warming) is one direction with it, and no fit can tell them apart."""
    blocks: dict[tuple[str, float], list[tuple[float, float]]] = {}
    for rec in recordings:
        if rec.start_time_s is not None and "flux_Wb" in rec.channels:
            blocks.setdefault((rec.rig, round(rec.current_pp_a, 6)), []).append((rec.start_time_s, rec.frequency_hz))
    ordered = []
    for block in blocks.values():
        if len({freq for _, freq in block}) >= 3:  # a point repeated at one frequency has no order to hide in
            f = [freq for _, freq in sorted(block)]
            ordered.append(f == sorted(f) or f == sorted(f, reverse=True))
    return bool(ordered) and all(ordered)


def preset_value(preset: Mapping[str, Any], path: str) -> float:
    """A number in a preset by its dotted path (``instrument.fn_hz``)."""
    node: Any = preset
    for part in path.split("."):
        node = node[part]
    return float(node)


def with_value(preset: Mapping[str, Any], path: str, value: float) -> dict[str, Any]:
    """A copy of ``preset`` with the number at ``path`` set (the caller re-checks it with load_rig)."""
    p = copy.deepcopy(dict(preset))
    node = p
    parts = path.split(".")
    for part in parts[:-1]:
        node = node[part]
    node[parts[-1]] = value
    return p


def with_effects(preset: Mapping[str, Any], effects: Mapping[str, Mapping[str, Any]]) -> dict[str, Any]:
    """A copy of ``preset`` whose effects are exactly ``effects`` (name -> parameters)."""
    p = copy.deepcopy({k: v for k, v in preset.items() if k != "_source"})
    p["effects"] = {name: dict(params) for name, params in effects.items()}
    return p


def replay(presets: Mapping[str, Mapping[str, Any]], points: Sequence[Point], *, periods: int = 2) -> list[Replayed]:
    """Noiseless simulated recordings of ``points`` (same order), each ``periods`` periods around the
    middle of the recorded span, on the day's clock.  ``presets`` maps a rig name to the preset
    (effects included) that simulates it."""
    out: dict[int, Replayed] = {}
    for rig_name in dict.fromkeys(p.rig for p in points):
        index = [i for i, p in enumerate(points) if p.rig == rig_name]
        out.update(zip(index, replay_rig(presets[rig_name], [points[i] for i in index], periods=periods)))
    return [out[i] for i in range(len(points))]


#: A record this short is replayed whole: a lightly damped mode's transient after a change of operating
#: point (the frame's, 9 ms) decays through it, and only the whole record averages it as the data did.
WHOLE_RECORD_SAMPLES = 25_000


@dataclass(frozen=True)
class Replayed:
    """One point's replay: ``periods`` periods at the middle of the recorded span (the harmonics), and
    as many at its start and end (the DC's curvature along the record: a transient's mean over a record
    is not its value at the middle)."""

    middle: Recording
    edges: tuple[Recording, Recording] | None  # None when the record is too short to hold three windows
    span: tuple[float, float]  # the recorded span, seconds on the day's clock


def replay_rig(preset: Mapping[str, Any], points: Sequence[Point], *, periods: int = 2) -> list[Replayed]:
    """:func:`replay` of one rig's points (same order): one running rig, as the bench day had."""
    out: list[Replayed | None] = [None] * len(points)
    sim: SimulatedRig | None = None
    previous_end = 0.0
    memory = memory_s(preset)
    pre_roll = 0.0
    # a record's DC is the mean of a drift or a transient along it, not the middle's value
    drifts = memory > 0 or any(e in (preset.get("effects") or {}) for e in CLOCKED)
    for i in sorted(range(len(points)), key=lambda i: points[i].start_time_s):
        p = points[i]
        try:
            sim, previous_end, pre_roll, out[i] = _replay_point(sim, preset, p, previous_end, pre_roll, memory,
                                                                drifts, periods)
        except SimulationError as err:  # which recording: a sidecar naming another rig lands here
            raise SimulationError(f"{p.name}: its replay on the simulated {p.rig} at {p.frequency_hz:g} Hz, "
                                  f"{p.current_pp_a:.3g} A-pp failed (is the sidecar's rig the one recorded?): "
                                  f"{err}") from err
    return [r for r in out if r is not None]


def _replay_point(sim: SimulatedRig | None, preset: Mapping[str, Any], p: Point, previous_end: float,
                  pre_roll: float, memory: float, drifts: bool, periods: int
                  ) -> tuple[SimulatedRig, float, float, Replayed]:
    """One point of :func:`replay_rig`: the rig (made, or moved on to the point), the point's end,
    its pre-roll and what the replay of it is."""
    if sim is None or sim.fs_hz != p.fs_hz:  # a stepped sine may change rate: a new rig, no memory kept
        # the bench day's procedure: a rig settles 5 periods (at least 20 ms) before its first
        # recording; its filters' transients start there
        sim = SimulatedRig(load_rig(preset), fs_hz=p.fs_hz, seed=0,
                           effects={e: False for e in MEASURED_DIRECTLY}, frequency_hz=p.frequency_hz,
                           current_pp_a=p.current_pp_a, warmup_s=settle_s(p.frequency_hz),
                           clock_offset_s=p.start_time_s)
    else:  # the operating point changes when the previous recording ends (the rig ran on through it)
        _advance(sim, previous_end, pre_roll)  # the previous point's: its state when the point changes
        sim.set_excitation(p.frequency_hz, p.current_pp_a)
    pre_roll = max(settle_s(p.frequency_hz), RING_DOWN_S, memory)
    end = p.start_time_s + p.duration_s
    keep = (max(2, int(periods)) + 0.5) / p.frequency_hz
    begin = p.start_time_s + max(0.0, 0.5 * (p.duration_s - keep))
    if p.duration_s * p.fs_hz <= WHOLE_RECORD_SAMPLES:  # short: the whole record, its transients as they were
        replayed = Replayed(_window(sim, p.start_time_s, p.duration_s, pre_roll), None, (p.start_time_s, end))
    elif drifts and p.duration_s >= 3.5 * keep:
        first = _window(sim, p.start_time_s, keep, pre_roll)
        middle = _window(sim, begin, keep, pre_roll)
        last = _window(sim, end - keep, keep, pre_roll)
        averaged = p.averaged_s if math.isfinite(p.averaged_s) else p.duration_s
        replayed = Replayed(middle, (first, last), (p.start_time_s, p.start_time_s + averaged))
    else:
        replayed = Replayed(_window(sim, begin, keep, pre_roll), None, (p.start_time_s, end))
    return sim, end, pre_roll, replayed


def _window(sim: SimulatedRig, begin: float, keep: float, pre_roll: float) -> Recording:
    _advance(sim, begin, pre_roll)
    block = sim.read(max(2, int(math.ceil(keep * sim.fs_hz))))
    meta = sim.metadata()
    meta["start_time_s"] = begin
    return Recording(None, sim.fs_hz, dict(block.channels), meta)


def record_mean(values: Sequence[float], centres: Sequence[float], span: tuple[float, float]) -> float:
    """The mean over ``span`` of the quadratic through three (time, value) points."""
    c = np.polyfit(np.asarray(centres) - span[0], np.asarray(values), 2)
    T = span[1] - span[0]
    return float(c[0] * T ** 2 / 3 + c[1] * T / 2 + c[2])


def settle_s(frequency_hz: float) -> float:
    """How long the bench day settles a rig at a new operating point (``sim_backend.bench_day``)."""
    return default_settle_s(frequency_hz)


#: Effects that follow the day's clock (the DC moves along a record).
CLOCKED = ("force_offset_drift", "magnet_thermal_drift")
#: A skip leaves a step in the rig's state; the load cell's lightly damped mode (zeta 0.01 at 4.5 kHz)
#: rings 3.5 ms per neper: this much pre-roll leaves 1e-7 of it.
RING_DOWN_S = 0.06


#: The longest memory a replay simulates (s).  A high-pass is the only memory (:func:`memory_s`), and
#: with one the force's DC is not compared (:data:`.select.DC_BLIND`): what is left to get right is its
#: transient's curvature inside the kept windows, which leaks into the force's harmonics.  Measured on
#: ``ecore_pm`` replays of our bench day and of the independent bench's (100 s pauses), time constants
#: 0.25-64 s: after 2 s every force harmonic is within 0.02 noise floors of a replay that follows 5 tau
#: of memory (2 noise floors with none, at 0.25 s).  The 20 s this was, a bench day's pause, made the
#: independent bench's high-pass days the slowest of both suites (51 and 69 s of CPU, 19 and 26 s now).
MEMORY_CAP_S = 2.0


def memory_s(preset: Mapping[str, Any]) -> float:
    """How long a rig remembers what it did: five of its charge amplifier's time constant (the force's
    DC after each change of operating point), at most MEMORY_CAP_S; 0 without a high-pass.  Longer
    pauses need not be simulated.  An integrator's leak is not counted: the flux's DC is never compared
    (an integrator's DC is where it was reset), and its ramp is separated from the harmonics by the
    features.  Nor is a high-pass followed to the end of its transient: with one, the force's DC is
    not compared either (:data:`.select.DC_BLIND`), and its harmonics have settled by the cap."""
    effects = preset.get("effects") or {}
    if "charge_amp_highpass" not in effects:
        return 0.0
    tau = float({**CATALOGUE["charge_amp_highpass"].defaults, **(effects["charge_amp_highpass"] or {})}["time_constant_s"])
    return min(5.0 * tau, MEMORY_CAP_S)


def _advance(sim: SimulatedRig, t_s: float, pre_roll_s: float) -> None:
    """Bring the rig to ``t_s`` on the day's clock, simulating only the last ``pre_roll_s`` of the way
    (what it remembers, and its settling): the pauses of a bench day are most of its clock, and a rig
    with nothing slow in it forgets them."""
    skip = int(round((t_s - pre_roll_s - sim.clock_offset_s) * sim.fs_hz)) - sim.next_index
    if skip > 0:
        sim.skip(skip)
    _run_until(sim, t_s)


def _run_until(sim: SimulatedRig, t_s: float, chunk: int = 200_000) -> None:
    """Run the rig (discarding samples) until its next sample is at ``t_s`` on the day's clock."""
    left = int(round((t_s - sim.clock_offset_s) * sim.fs_hz)) - sim.next_index
    while left > 0:
        n = min(chunk, left)
        sim.read(n)
        left -= n


def replayed_features(rep: Replayed) -> RecordFeatures:
    """A replayed point's features: the middle window's harmonics, each channel's DC the record's mean
    (the quadratic through the start, middle and end windows), as the recording's features hold it."""
    f = record_features(rep.middle, frequency_hz=rep.middle.metadata["generator_frequency_Hz"])
    if rep.edges is None:
        return f
    (t_first, dc_first), (t_last, dc_last) = (_window_mean(w) for w in rep.edges)
    centres = [t_first, rep.middle.start_time_s + 0.5 * f.periods / f.frequency_hz, t_last]
    harmonics = {}
    for ch, h in f.harmonics.items():
        h = h.copy()
        h[0] = record_mean([dc_first[ch], h[0].real, dc_last[ch]], centres, rep.span)
        harmonics[ch] = h
    return dataclasses.replace(f, harmonics=harmonics)


def _window_mean(window: Recording) -> tuple[float, dict[str, float]]:
    """A noiseless window's mean over its whole periods (which start at its first sample), and when."""
    f = window.metadata["generator_frequency_Hz"]
    periods = math.floor((window.n - 1) / window.fs_hz * f + 1e-9)
    n = int(round(periods * window.fs_hz / f))
    return window.start_time_s + 0.5 * periods / f, {ch: float(np.mean(x[:n])) for ch, x in window.channels.items()}


def replay_features(preset: Mapping[str, Any], points: Sequence[Point]) -> list[RecordFeatures]:
    """The features of one rig's replay (what a worker process computes)."""
    return [replayed_features(r) for r in replay_rig(preset, points)]
