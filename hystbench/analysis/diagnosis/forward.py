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
import math
from dataclasses import dataclass
from typing import Any, Iterable, Mapping, Sequence

from ...config import load_rig
from ...formats.recording import Recording
from ...sim_backend.rig import SimulatedRig
from ..method import recording_name

__all__ = ["Point", "points_of", "replay", "MEASURED_DIRECTLY", "with_effects", "with_value", "preset_value"]

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


def points_of(recordings: Sequence[Recording]) -> tuple[list[Point], bool]:
    """The recordings' points, and whether their sidecars gave the clock.  Without ``start_time_s``
    the recordings are taken as recorded back to back in the order given (the replay then has no
    slow effect to compare)."""
    clocked = all(r.start_time_s is not None for r in recordings)
    points, t = [], 0.0
    for rec in recordings:
        start = float(rec.start_time_s) if clocked else t
        points.append(Point(recording_name(rec), rec.rig, rec.frequency_hz, rec.current_pp_a, start, rec.duration_s,
                            rec.fs_hz))
        t = start + rec.duration_s
    return points, clocked


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


def replay(presets: Mapping[str, Mapping[str, Any]], points: Sequence[Point], *, periods: int = 2) -> list[Recording]:
    """Noiseless simulated recordings of ``points`` (same order), each ``periods`` periods around the
    middle of the recorded span, on the day's clock.  ``presets`` maps a rig name to the preset
    (effects included) that simulates it."""
    out: list[Recording | None] = [None] * len(points)
    for rig_name in dict.fromkeys(p.rig for p in points):
        order = sorted((i for i, p in enumerate(points) if p.rig == rig_name), key=lambda i: points[i].start_time_s)
        sim: SimulatedRig | None = None
        for i in order:
            p = points[i]
            if sim is None or sim.fs_hz != p.fs_hz:  # a stepped sine may change rate: a new rig, no memory kept
                sim = SimulatedRig(load_rig(presets[rig_name]), fs_hz=p.fs_hz, seed=0,
                                   effects={e: False for e in MEASURED_DIRECTLY}, frequency_hz=p.frequency_hz,
                                   current_pp_a=p.current_pp_a)
                # the bench day's procedure settles a rig before its first recording (5 periods, at
                # least 20 ms): its filters' transients start there, not at the first recorded sample
                sim.clock_offset_s = p.start_time_s - max(5.0 / p.frequency_hz, 0.02) - sim._next_index / sim.fs_hz
            else:
                sim.set_excitation(p.frequency_hz, p.current_pp_a)
            keep = (max(2, int(periods)) + 0.5) / p.frequency_hz
            begin = p.start_time_s + max(0.0, 0.5 * (p.duration_s - keep))
            _run_until(sim, begin)
            block = sim.read(max(2, int(math.ceil(keep * sim.fs_hz))))
            meta = sim.metadata()
            meta["start_time_s"] = begin
            meta["name"] = p.name
            out[i] = Recording(None, sim.fs_hz, dict(block.channels), meta)
    return [r for r in out if r is not None]


def _run_until(sim: SimulatedRig, t_s: float, chunk: int = 200_000) -> None:
    """Run the rig (discarding samples) until its next sample is at ``t_s`` on the day's clock."""
    left = int(round((t_s - sim.clock_offset_s) * sim.fs_hz)) - sim._next_index
    while left > 0:
        n = min(chunk, left)
        sim.read(n)
        left -= n


def rigs_of(points: Iterable[Point]) -> list[str]:
    return list(dict.fromkeys(p.rig for p in points))
