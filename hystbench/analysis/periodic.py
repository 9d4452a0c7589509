"""One period of a periodic record: its true frequency and its synchronous average.

The generator and the ADC run on their own clocks, tens of ppm apart, so a record holds a
non-integer number of samples per period, at a frequency known only after the fact.  Averaging at
the nominal frequency, or at whole samples, would smear the loops the method and the compensator
measure.  So, for every caller (the force error, the compensator's identification and its live
meter, the demo's loops):

- :func:`estimate_frequency`: the true frequency, by the four-parameter least-squares sine fit
  (IEEE Std 1057, with harmonics), which reaches the Cramer-Rao bound (the phase advance between
  the record's two halves, which the compensator used before, stays sqrt(4/3) = 1.15x above it).
- :func:`period_average`: every whole period resampled (cubic spline) at the same phases of that
  frequency and averaged, with the rms of one period about the average (the sensor noise) and the
  average with alternating signs (every periodic part cancels, the averaged noise stays: the
  honest noise floor of the average).  Phase 0 is sample 0.  The spline is built and evaluated
  period chunk by period chunk, so memory stays bounded however long the record.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Mapping

import numpy as np
from numpy.typing import ArrayLike
from scipy.interpolate import CubicSpline

from ..formats.recording import Recording
from .estimation import estimation_errors, sine_fit
from .method import recording_name

__all__ = ["PeriodAverage", "estimate_frequency", "period_average", "synchronous_average"]

#: Resampled values evaluated at once per channel (8 MiB of float64 each); longer records go in period chunks.
CHUNK_VALUES = 1 << 20
#: Samples on each side of a chunk that its spline also spans: the end conditions of a cubic
#: spline fade by 2 - sqrt(3) = 0.27 per knot, so 32 knots in they are below 1e-18 of themselves.
_MARGIN = 32


@dataclass(frozen=True)
class PeriodAverage:
    """One period of each channel at ``phase`` (cycles, 0 <= phase < 1; phase 0 = sample 0)."""

    frequency_hz: float
    periods: int
    phase: np.ndarray
    channels: dict[str, np.ndarray]
    noise_rms: dict[str, float]  # rms of a single period about the average (sensor noise); nan for one period
    alternating: dict[str, np.ndarray]  # an even number of periods with alternating signs; nan for one period

    @property
    def t_s(self) -> np.ndarray:
        return self.phase / self.frequency_hz

    def floor(self, name: str) -> float:
        """max |alternating average| of a channel: the averaged noise of this record length."""
        return float(np.max(np.abs(self.alternating[name])))


def estimate_frequency(x: ArrayLike, fs_hz: float, nominal_hz: float, *, harmonics: int = 5) -> float:
    """The true frequency of a periodic record near ``nominal_hz`` (Hz): the sine fit of DC and
    the first ``harmonics`` harmonics (those below fs/2), frequency estimated.  ``ValueError``
    naming the parameter for a record the fit cannot take (flat, shorter than two periods)."""
    if not (math.isfinite(nominal_hz) and nominal_hz > 0):
        raise ValueError(f"nominal_hz must be finite and > 0 Hz, got {nominal_hz!r}")
    ks = tuple(k for k in range(1, max(1, int(harmonics)) + 1) if k * nominal_hz < 0.5 * fs_hz) or (1,)
    return float(sine_fit(np.asarray(x, float), fs_hz, nominal_hz, harmonics=ks).frequency_hz)


def period_average(channels: Mapping[str, ArrayLike], fs_hz: float, frequency_hz: float, n_points: int = 1000,
                   *, names: tuple[str, ...] | None = None) -> PeriodAverage:
    """Average the whole periods of ``channels`` (sampled at ``fs_hz`` from sample 0) at
    ``frequency_hz``, the estimated true frequency, on ``n_points`` phases.  ``ValueError`` for
    arguments it cannot take or a record shorter than one period."""
    names = tuple(channels) if names is None else tuple(names)
    if not (math.isfinite(fs_hz) and fs_hz > 0):
        raise ValueError(f"fs_hz must be finite and > 0 Hz, got {fs_hz!r}")
    if not (math.isfinite(frequency_hz) and frequency_hz > 0) or int(n_points) != n_points or n_points < 8:
        raise ValueError(f"frequency_hz must be finite and > 0, n_points a whole number >= 8; got "
                         f"{frequency_hz!r}, {n_points!r}")
    missing = [c for c in names if c not in channels]
    if missing or not names:
        raise ValueError(f"no channel {missing[0]!r} to average" if missing else "no channels to average")
    data = {c: np.asarray(channels[c], float) for c in names}
    sizes = {x.size for x in data.values()}
    if len(sizes) != 1 or any(x.ndim != 1 for x in data.values()):
        raise ValueError(f"channels must be 1-D and of one length, got {sorted(sizes)}")
    n = sizes.pop()
    periods = int(np.floor((n - 1) / fs_hz * frequency_hz + 1e-9)) if n else 0
    if periods < 1:
        raise ValueError(f"{n} samples at {fs_hz:g} Hz are shorter than one period of {frequency_hz:g} Hz")
    n_points = int(n_points)
    phase = np.arange(n_points) / n_points
    step = max(1, CHUNK_VALUES // n_points)
    chunks = [(p0, min(periods, p0 + step)) for p0 in range(0, periods, step)]
    mean, m2, alt = _average_all(np.stack(list(data.values()), axis=-1), fs_hz, frequency_hz, phase, chunks, periods)
    avg = {name: mean[:, c] for c, name in enumerate(data)}
    alts = {name: alt[:, c] for c, name in enumerate(data)}
    noise = {name: float(np.sqrt(np.sum(m2[:, c]) / (periods * n_points))) if periods > 1 else math.nan
             for c, name in enumerate(data)}
    return PeriodAverage(float(frequency_hz), periods, phase, avg, noise, alts)


def _average_all(x: np.ndarray, fs_hz: float, frequency_hz: float, phase: np.ndarray,
                 chunks: list[tuple[int, int]], periods: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(mean, sum of squared deviations from it, alternating mean) at each phase (rows) of each
    channel (the columns of ``x``), chunk by chunk (the chunks' means and deviations merged as Chan
    et al. do, exact to rounding); one spline through every channel, so one banded solve."""
    even = periods - periods % 2
    shape = (phase.size, x.shape[1])
    mean, m2, alt = np.zeros(shape), np.zeros(shape), np.zeros(shape)
    count = 0
    for p0, p1 in chunks:
        when = (np.arange(p0, p1)[:, None] + phase[None, :]) / frequency_hz
        lo = max(0, int(np.floor(when[0, 0] * fs_hz)) - _MARGIN)
        hi = min(x.shape[0], int(np.ceil(when[-1, -1] * fs_hz)) + 1 + _MARGIN)
        grid = CubicSpline(np.arange(lo, hi) / fs_hz, x[lo:hi], axis=0)(when)  # (periods, phases, channels)
        m_c = grid.mean(axis=0)
        k = p1 - p0
        delta = m_c - mean
        mean = mean + delta * (k / (count + k))
        m2 += ((grid - m_c) ** 2).sum(axis=0) + delta ** 2 * (count * k / (count + k))
        count += k
        rows = max(0, min(p1, even) - p0)
        if rows:
            signs = np.where(np.arange(p0, p0 + rows) % 2 == 0, 1.0, -1.0)[:, None, None]
            alt += (grid[:rows] * signs).sum(axis=0)
    return mean, m2, (alt / even if even else np.full(shape, math.nan))


def synchronous_average(rec: Recording, frequency_hz: float, n_points: int = 1000,
                        names: tuple[str, ...] | None = None) -> PeriodAverage:
    """:func:`period_average` of a recording's channels; its errors as ``EstimationError`` naming it."""
    with estimation_errors(recording_name(rec)):
        return period_average(rec.channels, rec.fs_hz, frequency_hz, n_points, names=names)
