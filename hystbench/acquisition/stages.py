"""The estimation stage of the pipeline: the offline method over a live stream.

:class:`WindowEstimator` cuts the stream into windows of whole periods anchored on sample indices
(not on block boundaries, so any cut of the same samples gives the same estimates) and runs
:func:`~.method.measure_window` on each.  Runs follow the :class:`~hystbench.messages.OperatingPoint`
the sources put in every block's meta (see :mod:`.sources`); what the rig preset says (is it an
E-core, has it a magnet) is read once, when the estimator is made.
"""

from __future__ import annotations

import math
from typing import Any, Mapping

import numpy as np

from ..blocks import SampleBlock
from ..config import load_rig
from ..errors import BenchError, ConfigError
from ..formats.recording import sidecar_point
from ..messages import Estimate, OperatingPoint
from ..analysis.settling import settle_samples, settling_time_s

__all__ = ["WindowEstimator"]


_METHOD_CHANNELS = ("current_A", "flux_Wb", "force_N")


class WindowEstimator:
    """Delays over sliding windows of whole periods: the streaming face of the offline method.

    A window is ``periods`` periods of the nominal frequency (rounded to whole samples); one ends
    every ``hop`` samples (``hop_periods`` periods, at least ``min_hop_s``), counted from the
    start of the current *run*: contiguous samples at one operating point, minus the transient
    after a change: ``settle_s`` (default: the rig's :func:`~.settling.settling_time_s`, ten of
    its instrument's slowest time constants) or ``settle_periods`` periods (the iron's loop),
    whichever is longer.  A gap, an overrun or a new operating point starts a new run, so windows
    never straddle them or the settling after them; windows with the output off or marked
    ``settling`` (samples that may predate a command) are not estimated.  Above ``max_fs_hz``
    each channel is averaged over ``decimate`` samples first (the same delay in every channel, so
    the delays between them are unchanged).

    ``metadata`` is the source's recording sidecar: its rig, and the nominal operating point for
    blocks whose meta names none.  ``append`` copies the samples in (so a ring view can be
    released at once); ``estimates`` returns the :class:`~hystbench.messages.Estimate` s of the
    windows completed since.  E-core rigs get the method (:func:`~.method.measure_window`) with
    all its checks; other rigs the plain :func:`~.estimation.phase_delay` of force (and flux)
    behind current.  A window the method refuses gives an estimate with ``error`` set; gross
    outliers are left out of the fits and named by source sample index under ``outliers``.

    Each estimate names the waveform ``table`` its samples were played with.  With
    ``keep_windows``, :meth:`windowed` pairs each estimate with its samples as a
    :class:`~hystbench.blocks.SampleBlock` (at the decimated rate, ``command_V`` included when the
    source has it, its operating point in ``meta``): a learning compensator averages them; they
    are never published.
    """

    def __init__(self, fs_hz: float, metadata: Mapping[str, Any], *, periods: float = 10.0,
                 hop_periods: float | None = None, min_hop_s: float = 0.1, settle_periods: float = 2.0,
                 max_fs_hz: float = 100_000.0, keep_windows: bool = False, settle_s: float | None = None) -> None:
        if not periods >= 2:
            raise ConfigError(f"estimation periods must be >= 2, got {periods}")
        if settle_s is not None and not settle_s >= 0:
            raise ConfigError(f"estimation settle_s must be >= 0, got {settle_s}")
        self.fs_hz = float(fs_hz)
        self.periods, self.hop_periods = float(periods), float(hop_periods or periods)
        self.min_hop_s, self.settle_periods = float(min_hop_s), float(settle_periods)
        self.settle_s = settling_time_s(metadata) if settle_s is None else float(settle_s)
        self.decimate = max(1, int(self.fs_hz // max_fs_hz))
        self.keep_windows = bool(keep_windows)
        self.rig = str(metadata.get("rig", ""))
        self.nominal = sidecar_point(metadata)  # for blocks whose meta names no operating point
        try:
            preset = load_rig(self.rig)
        except BenchError:
            preset = {}
        self.method = preset.get("actuator") == "ecore"
        self.magnet = "magnet" in preset
        from ..analysis.estimation import phase_delay  # imported here, not at the first window (scipy: ~1 s)
        from ..analysis.method import measure_window

        self._phase_delay, self._measure_window = phase_delay, measure_window
        self._warm()
        self.errors = 0
        self._out: list[tuple[Estimate, SampleBlock | None]] = []
        self.reset()

    def _warm(self) -> None:
        """Fit one synthetic window now, so numba compiles (or loads from its cache) the fits'
        kernels here and not at the first window: 0.5 s cached, seconds cold, while the stream
        fills the ring behind a stage that then drops samples."""
        n = 4000
        t = np.arange(n) / 1e5
        noise = np.random.default_rng(0).normal(0.0, 1e-3, (3, n))
        x = {c: np.cos(2 * np.pi * 320.0 * (t - d)) + e for c, d, e in zip(_METHOD_CHANNELS, (0.0, 1e-5, 2e-5), noise)}
        try:
            if self.method:
                self._measure_window(x, 1e5, 320.0, magnet=self.magnet, where="warm-up window")
            else:
                self._phase_delay(x["current_A"], x["force_N"], 1e5, 320.0)
        except (BenchError, ValueError):  # only the compiling matters here
            pass

    def reset(self) -> None:
        """Forget the run in progress (after torn or lost samples)."""
        self._point: OperatingPoint | None = None
        self._buf: dict[str, np.ndarray] = {}
        self._start = 0  # source index of _buf[...][0]
        self._fill = 0
        self._run_start = 0
        self._end: int | None = None
        self._next_end = 0

    def _begin(self, block: SampleBlock, point: OperatingPoint) -> None:
        self.reset()
        self._point = point
        self._f, self._ipp = point.frequency_hz, point.current_pp_a
        self._where = f"{self.rig} window at {self._f:g} Hz, {self._ipp:g} A-pp"
        spp = self.fs_hz / self._f
        k = self.decimate
        self._win = max(k, int(round(self.periods * spp / k)) * k)
        self._hop = max(k, int(round(max(self.hop_periods * spp, self.min_hop_s * self.fs_hz) / k)) * k)
        self._run_start = block.first_index
        settle = settle_samples(self.settle_s, self.settle_periods, self.fs_hz, self._f)
        self._next_end = block.first_index + settle + self._win
        wanted = _METHOD_CHANNELS + (("command_V",) if self.keep_windows else ())
        self._names = [c for c in wanted if c in block.channels]
        cap = self._win + self._hop + block.n
        self._buf = {c: np.empty(cap, dtype=np.float64) for c in self._names}
        self._start, self._fill = block.first_index, 0

    def append(self, block: SampleBlock) -> None:
        if block.n == 0:
            return
        point = block.point if block.point is not None else self.nominal
        if not 0 < point.frequency_hz < math.inf:  # no period to window by (a damaged log's block: a
            self._point, self._end = point, block.end_index  # division by its 0 Hz ended a replay)
            return
        if point != self._point or block.first_index != self._end:
            self._begin(block, point)
        self._end = block.end_index
        if not point.excited or len([c for c in self._names if c in _METHOD_CHANNELS]) < 2:
            return
        need = self._fill + block.n
        cap = next(iter(self._buf.values())).size
        if need > cap:  # drop what no future window needs, then grow if still short
            keep_from = max(self._next_end - self._win, self._start)
            drop = min(keep_from - self._start, self._fill)
            for c, x in self._buf.items():
                x[: self._fill - drop] = x[drop:self._fill]
            self._start += drop
            self._fill -= drop
            need = self._fill + block.n
            if need > cap:
                self._buf = {c: np.concatenate([x[: self._fill], np.empty(need - self._fill)]) for c, x in self._buf.items()}
        for c in self._names:
            self._buf[c][self._fill:self._fill + block.n] = block.channels[c]
        self._fill += block.n
        while self._next_end <= self._start + self._fill:
            self._out.append(self._estimate(self._next_end - self._win, self._next_end))
            self._next_end += self._hop

    def windowed(self) -> list[tuple[Estimate, SampleBlock | None]]:
        """The windows completed since the last call: each estimate with its samples (None unless
        ``keep_windows``)."""
        out, self._out = self._out, []
        return out

    def estimates(self) -> list[Estimate]:
        """The estimates of the windows completed since the last call."""
        return [e for e, _ in self.windowed()]

    def push(self, block: SampleBlock) -> list[Estimate]:
        """``append`` then ``estimates``."""
        self.append(block)
        return self.estimates()

    def _window(self, a: int, b: int) -> tuple[dict[str, np.ndarray], float]:
        i, k = a - self._start, self.decimate
        chans = {c: x[i:i + b - a] for c, x in self._buf.items()}
        if k > 1:
            chans = {c: x.reshape(-1, k).mean(axis=1) for c, x in chans.items()}
        return chans, self.fs_hz / k

    def _estimate(self, a: int, b: int) -> tuple[Estimate, SampleBlock | None]:
        chans, fs = self._window(a, b)
        window = None
        if self.keep_windows:
            window = SampleBlock(a // self.decimate, fs, {c: x.copy() for c, x in chans.items()},
                                 meta=self._point.to_meta())
            chans = {c: x for c, x in chans.items() if c in _METHOD_CHANNELS}
        at = {"first_index": int(a), "end_index": int(b), "t_ns": round(b * 1e9 / self.fs_hz),
              "nominal_frequency_hz": self._f, "current_pp_a": self._ipp, "table": self._point.table}
        try:
            if self.method:
                d = self._measure_window(chans, fs, self._f, magnet=self.magnet, current_pp_a=self._ipp,
                                         where=self._where)
                f, fse, harmonic = d.frequency_hz, d.frequency_std_hz, d.harmonic
                delays, stds, found = d.delays_s, d.delays_std_s, d.outliers
            else:
                f, fse, harmonic, delays, stds, found = self._phase_delays(chans, fs)
        except (BenchError, ValueError) as err:
            self.errors += 1
            return Estimate(**at, error=str(err)), window
        # window sample -> source sample index (the first of its group when decimated)
        outliers = {c: tuple(a + self.decimate * i for i in v) for c, v in found.items() if len(v)}
        return Estimate(**at, frequency_hz=f, frequency_std_hz=fse, harmonic=harmonic, delays_s=dict(delays),
                        delays_std_s=dict(stds), phases_deg={k: 360.0 * f * v for k, v in delays.items()},
                        phases_std_deg={k: 360.0 * f * v for k, v in stds.items()}, outliers=outliers,
                        outliers_excluded=bool(outliers)), window

    def _phase_delays(self, chans: Mapping[str, np.ndarray], fs_hz: float) -> tuple:
        """Rigs other than E-cores: force (total) and flux (hysteresis) behind current."""
        x = chans["current_A"]
        delays, stds, f, fse = {}, {}, self._f, 0.0
        found: dict[str, set[int]] = {}
        for name, c in (("total", "force_N"), ("hysteresis", "flux_Wb")):
            if chans.get(c) is not None:
                r = self._phase_delay(x, chans[c], fs_hz, self._f)
                delays[name], stds[name] = float(r.delay_s), float(r.delay_se_s)
                f, fse = float(r.frequency_hz), float(r.frequency_se_hz)
                found.setdefault("current_A", set()).update(r.x.outliers.tolist())
                found.setdefault(c, set()).update(r.y.outliers.tolist())
        return f, fse, 1, delays, stds, {c: sorted(v) for c, v in found.items()}
