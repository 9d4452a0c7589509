"""The estimation stage of the pipeline: the offline method over a live stream.

:class:`WindowEstimator` cuts the stream into windows of whole periods anchored on sample indices
(not on block boundaries, so any cut of the same samples gives the same estimates) and runs
:func:`~.method.measure_delays` on each.  Runs follow the operating point the sources put in
every block's meta (see :mod:`.sources`).
"""

from __future__ import annotations

from typing import Any, Mapping

import numpy as np

from ..blocks import SampleBlock
from ..config import load_rig
from ..errors import BenchError, ConfigError
from ..formats.recording import Recording
from ..analysis.settling import settle_samples, settling_time_s
from .sources import OPERATING_KEYS

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
    ``settling`` (samples that may predate a command) are not estimated.  Above ``max_fs_hz`` each channel is averaged over ``decimate`` samples first (the
    same delay in every channel, so the delays between them are unchanged).

    ``append`` copies the samples in (so a ring view can be released at once); ``estimates``
    returns the windows completed since.  E-core rigs get :func:`~.method.measure_delays` with all
    its checks; other rigs the plain :func:`~.estimation.phase_delay` of force (and flux) behind
    current.  A window the method refuses gives an estimate with ``error`` set; gross outliers are
    left out of the fits and named by source sample index under ``outliers`` (channel -> indices).

    Each estimate names the waveform ``table`` its samples were played with.  With
    ``keep_windows`` it also carries its samples under ``window`` (``fs_Hz`` and ``channels``,
    ``command_V`` included when the source has it): a learning compensator averages them; the
    pipeline takes them out before the estimate is published.
    """

    def __init__(self, fs_hz: float, metadata: Mapping[str, Any], *, periods: float = 10.0,
                 hop_periods: float | None = None, min_hop_s: float = 0.1, settle_periods: float = 2.0,
                 max_fs_hz: float = 100_000.0, keep_windows: bool = False, settle_s: float | None = None) -> None:
        if not periods >= 2:
            raise ConfigError(f"estimation periods must be >= 2, got {periods}")
        if settle_s is not None and not settle_s >= 0:
            raise ConfigError(f"estimation settle_s must be >= 0, got {settle_s}")
        self.fs_hz = float(fs_hz)
        self.metadata = dict(metadata)
        self.periods, self.hop_periods = float(periods), float(hop_periods or periods)
        self.min_hop_s, self.settle_periods = float(min_hop_s), float(settle_periods)
        self.settle_s = settling_time_s(metadata) if settle_s is None else float(settle_s)
        self.decimate = max(1, int(self.fs_hz // max_fs_hz))
        self.keep_windows = bool(keep_windows)
        rig = str(self.metadata.get("rig", ""))
        try:
            preset = load_rig(rig)
        except BenchError:
            preset = {}
        self.method = preset.get("actuator") == "ecore"
        from ..analysis.estimation import phase_delay  # imported here, not at the first window (scipy: ~1 s)
        from ..analysis.method import measure_delays

        self._phase_delay, self._measure_delays = phase_delay, measure_delays
        self.errors = 0
        self._out: list[dict] = []
        self.reset()

    def reset(self) -> None:
        """Forget the run in progress (after torn or lost samples)."""
        self._key: tuple | None = None
        self._table = 0
        self._buf: dict[str, np.ndarray] = {}
        self._start = 0  # source index of _buf[...][0]
        self._fill = 0
        self._run_start = 0
        self._end: int | None = None
        self._next_end = 0

    def _begin(self, block: SampleBlock) -> None:
        self.reset()
        m = block.meta
        self._key = tuple(m.get(k) for k in OPERATING_KEYS)
        self._f = float(m.get("frequency_hz") or self.metadata["frequency_Hz"])
        self._ipp = float(m.get("current_pp_a") if m.get("current_pp_a") is not None else self.metadata.get("current_pp_A", 0.0))
        self._on = m.get("output_on", 1.0) != 0.0 and not m.get("settling")
        spp = self.fs_hz / self._f
        k = self.decimate
        self._win = max(k, int(round(self.periods * spp / k)) * k)
        self._hop = max(k, int(round(max(self.hop_periods * spp, self.min_hop_s * self.fs_hz) / k)) * k)
        self._run_start = block.first_index
        settle = settle_samples(self.settle_s, self.settle_periods, self.fs_hz, self._f)
        self._next_end = block.first_index + settle + self._win
        wanted = _METHOD_CHANNELS + (("command_V",) if self.keep_windows else ())
        self._names = [c for c in wanted if c in block.channels]
        self._table = int(m.get("table") or 0)
        cap = self._win + self._hop + block.n
        self._buf = {c: np.empty(cap, dtype=np.float64) for c in self._names}
        self._start, self._fill = block.first_index, 0

    def append(self, block: SampleBlock) -> None:
        if block.n == 0:
            return
        key = tuple(block.meta.get(k) for k in OPERATING_KEYS)
        if key != self._key or block.first_index != self._end:
            self._begin(block)
        self._end = block.end_index
        if not self._on or len([c for c in self._names if c in _METHOD_CHANNELS]) < 2:
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

    def estimates(self) -> list[dict]:
        out, self._out = self._out, []
        return out

    def push(self, block: SampleBlock) -> list[dict]:
        """``append`` then ``estimates``."""
        self.append(block)
        return self.estimates()

    def _window(self, a: int, b: int) -> tuple[dict[str, np.ndarray], float]:
        i, k = a - self._start, self.decimate
        chans = {c: x[i:i + b - a] for c, x in self._buf.items()}
        if k > 1:
            chans = {c: x.reshape(-1, k).mean(axis=1) for c, x in chans.items()}
        return chans, self.fs_hz / k

    def _estimate(self, a: int, b: int) -> dict:
        phase_delay, measure_delays = self._phase_delay, self._measure_delays
        chans, fs = self._window(a, b)
        out: dict[str, Any] = {"first_index": int(a), "end_index": int(b), "t_ns": round(b * 1e9 / self.fs_hz),
                               "nominal_frequency_Hz": self._f, "current_pp_A": self._ipp, "table": self._table,
                               "error": None}
        if self.keep_windows:
            out["window"] = {"fs_Hz": fs, "channels": {c: x.copy() for c, x in chans.items()}}
            chans = {c: x for c, x in chans.items() if c in _METHOD_CHANNELS}
        meta = {**{k: v for k, v in self.metadata.items() if k in ("rig",)}, "frequency_Hz": self._f,
                "sample_rate_Hz": fs, "current_pp_A": self._ipp}
        try:
            if self.method:
                d = measure_delays(Recording(None, fs, chans, meta))
                out.update(d.as_dict())
            else:
                x = chans["current_A"]
                delays, stds, f, fse = {}, {}, self._f, 0.0
                found: dict[str, set[int]] = {}
                for name, c in (("total", "force_N"), ("hysteresis", "flux_Wb")):
                    if chans.get(c) is not None:
                        r = phase_delay(x, chans[c], fs, self._f)
                        delays[name], stds[name] = float(r.delay_s), float(r.delay_se_s)
                        f, fse = float(r.freq_hz), float(r.freq_se_hz)
                        found.setdefault("current_A", set()).update(r.x.outliers.tolist())
                        found.setdefault(c, set()).update(r.y.outliers.tolist())
                outliers = {c: sorted(v) for c, v in found.items() if v}
                out.update({"frequency_Hz": f, "frequency_std_Hz": fse, "harmonic": 1, "delays_s": delays,
                            "delays_std_s": stds, "phases_deg": {k: 360 * f * v for k, v in delays.items()},
                            "phases_std_deg": {k: 360 * f * v for k, v in stds.items()},
                            "outliers": outliers, "outliers_excluded": bool(outliers)})
            # window sample -> source sample index (the first of its group when decimated)
            out["outliers"] = {c: [a + self.decimate * i for i in v] for c, v in out["outliers"].items()}
        except (BenchError, ValueError) as err:
            self.errors += 1
            out["error"] = str(err)
        return out
