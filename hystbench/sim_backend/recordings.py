"""Recordings of the simulated rig: one operating point, or a sweep of them.

What ``hystbench simulate``/``simulate-sweep`` write and what the compensator is identified on
(:func:`hystbench.compensator.sweeps.quick_models`), and the voice coil's stepped-sine sweep that
identifies the force instrument (paper Sec. IV).  A block the rig's ADC clipped gives a
recording with ``clipped: true`` in its sidecar (the recording format's flag), so the method
refuses it instead of trusting its phases; :func:`clipped_channels` says which channel and at
which full scale, for a refusal that names the effect parameter to change.
"""

from __future__ import annotations

from typing import Any, Callable, Iterable, Mapping

import numpy as np

from ..blocks import BlockFlags
from ..formats.recording import Recording
from .rig import DEFAULT_FS_HZ, SimulatedRig

__all__ = ["simulate_recording", "simulated_sweep", "simulate_voice_coil_sweep", "clipped_channels",
           "clipped_by_noise"]


def simulate_recording(rig: str | Mapping[str, Any], frequency_hz: float, current_pp_a: float, duration_s: float,
                       *, fs_hz: float = DEFAULT_FS_HZ, seed: int = 0,
                       effects: Mapping[str, Any] | None = None) -> Recording:
    """``duration_s`` of the simulated rig at one operating point, as a recording (sample 0 at t = 0)."""
    sim = SimulatedRig(rig, fs_hz=fs_hz, seed=seed, effects=effects, frequency_hz=frequency_hz,
                       current_pp_a=current_pp_a)
    block = sim.record(duration_s)
    meta = sim.metadata()
    if block.flags & BlockFlags.CLIP:
        meta["clipped"] = True
    return Recording(None, sim.fs_hz, dict(block.channels), meta)


def simulated_sweep(rig: str | Mapping[str, Any], freqs_hz: Iterable[float], ipps_a: Iterable[float], *,
                    seed: int = 0, duration_s: float | None = None, effects: Mapping[str, Any] | None = None,
                    fs_hz: float = DEFAULT_FS_HZ, tick: Callable[[], None] | None = None) -> list[Recording]:
    """Recordings of the simulated rig, one per (frequency, amplitude), frequency first, seeds
    ``seed``, ``seed + 1``, ...; by default 8 periods or 0.1 s, whichever is longer (what an
    identification needs, not what a figure needs).  ``tick()`` after each recording."""
    ipps = list(ipps_a)
    recs = []
    for n, (f, ipp) in enumerate((f, i) for f in freqs_hz for i in ipps):
        recs.append(simulate_recording(rig, f, ipp, duration_s or max(0.1, 8.0 / f), fs_hz=fs_hz, seed=seed + n,
                                       effects=effects))
        if tick is not None:
            tick()
    return recs


def simulate_voice_coil_sweep(rig: str | Mapping[str, Any], freqs_hz: Iterable[float], *, seed: int = 0, current_pp_a: float = 1.0,
                              samples_per_period: float = 25.0,
                              tick: Callable[[], None] | None = None) -> list[Recording]:
    """A stepped-sine sweep, one recording per frequency.  As a frequency-response analyser does,
    the sample rate follows the frequency (>= ``samples_per_period``, at least 100 kS/s) and each
    point lasts 20 ms or 5 periods, whichever is longer.  The simulated instrument is a bilinear
    discretisation: at 25 samples per period its charge amplifier's phase near 45 kHz is read at a
    0.5 % higher frequency, which an instrument fit turns into a 1e-3 rad error of the low-frequency
    delay; 100 samples per period cuts that 16x (what a force model at the 1e-3 level needs)."""
    recs = []
    for n, f in enumerate(freqs_hz):
        sim = SimulatedRig(rig, fs_hz=max(100_000.0, samples_per_period * round(f)), seed=seed + n, frequency_hz=f,
                           current_pp_a=current_pp_a)
        block = sim.record(max(0.02, 5.0 / f))
        recs.append(Recording(None, sim.fs_hz, dict(block.channels), sim.metadata()))
        if tick:
            tick()
    return recs


def clipped_by_noise(rec: Recording, channel: str) -> float | None:
    """Whether the sensor noise, not the signal, took ``channel`` (which clipped) to its ADC full
    scale: the signal's peak (the median of the samples at each phase of the excitation, which the
    noise does not move and the clip does not bias until the signal itself reaches it) when it stays
    below the clip level, else None (the signal reaches it: a smaller current or a larger full
    scale helps, less noise would not)."""
    eff = rec.metadata.get("effects") or {}
    q, noise = eff.get("adc_quantisation") or {}, eff.get("sensor_noise") or {}
    key = channel.lower()
    if key not in q or not float(noise.get(key, 0.0)) > 0.0 or not rec.frequency_hz > 0.0:
        return None
    full = float(q[key])
    lsb = 2.0 * full / 2 ** int(q["bits"])
    x = np.asarray(rec.channels[channel], dtype=float)
    bins = int(max(1, min(64, rec.fs_hz / rec.frequency_hz)))  # a bin: at most 1/64 period
    phase = np.floor(np.mod(rec.time_s() * rec.frequency_hz, 1.0) * bins).astype(int)
    order = np.argsort(phase, kind="stable")
    cuts = np.searchsorted(phase[order], np.arange(1, bins))
    medians = np.array([np.median(part) for part in np.split(x[order], cuts) if part.size])
    top, bottom = float(medians.max()), float(medians.min())
    if top >= full - 2 * lsb or bottom <= -full + lsb:  # the signal itself sits at the clip level
        return None
    return max(abs(top), abs(bottom))


def clipped_channels(rec: Recording) -> dict[str, float]:
    """The channels of a simulated recording that reached their ADC full scale, each with that
    full scale (its ``adc_quantisation`` parameter is the channel's name in lower case)."""
    q = (rec.metadata.get("effects") or {}).get("adc_quantisation") or {}
    if not rec.metadata.get("clipped") or "bits" not in q:
        return {}
    over = {}
    for ch, x in rec.channels.items():
        full = q.get(ch.lower())
        if full is not None and float(np.max(np.abs(x))) >= float(full) * (1 - 2.0 ** (1 - int(q["bits"]))):
            over[ch] = float(full)
    return over
