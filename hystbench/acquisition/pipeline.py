"""The real-time pipeline: source -> ring -> estimation (-> compensator) -> MCAP and zenoh.

Threads, each with a bounded hand-off and counters of what it had to drop:

- *source*: pulls blocks from the source, writes them into the ring and publishes them on zenoh
  right there, so raw data reaches subscribers with no hand-off at all.  Live, the ring never
  blocks the writer (a stage that falls behind loses counted samples); a ``lossless`` pipeline
  (the default for a source paced ``max``: a replay, a simulation) holds the source back until
  the slowest stage has room instead, so it loses nothing and gives what the live run gave;
- *estimate*: a ring reader; copies each run into the :class:`WindowEstimator` and releases the
  view (a lapped view resets the estimator: nothing torn is estimated), then emits each
  :class:`~hystbench.messages.Estimate` and hands it (with its window of samples, to a compensator
  that learns) to the compensator, whose state it emits;
- *record*: a ring reader writing raw blocks to MCAP, cut where the source cut them (so a log
  replayed and recorded again has the same blocks), plus the JSON messages others emit through
  a bounded queue (full: the message is dropped and counted).  A write the disk refuses ends
  this stage only (``log_write_failed`` on ``status``, ``on_log_error`` told at once): the source,
  the estimates and zenoh go on; :meth:`Pipeline.attach_recorder` starts logging again;
- *stats*: every ``stats_interval_s`` publishes per-stage counters on ``stats`` (and logs them).

``emit(topic, obj)`` is the one way a message leaves: to the recorder's queue, to zenoh and to
``listeners`` (callables, e.g. a live printout), each as the same JSON-able dict (a typed message
such as an :class:`~hystbench.messages.Estimate` is turned into one there, once).
"""

from __future__ import annotations

import logging
import os
import queue
import sys
import threading
import time
from collections import deque
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any, Callable, Mapping, Protocol, runtime_checkable

import numpy as np
from numpy.typing import DTypeLike

from ..blocks import BlockFlags, SampleBlock
from ..deadline import Deadline
from ..errors import CommandRefused, ConfigError, LogWriteError
from ..formats.mcaplog.schemas import COMPENSATOR, ESTIMATE, STATS, STATUS
from ..messages import CompensatorUpdate, Estimate
from .ring import RingBuffer, RingRead, RingReader
from .sources import Controllable
from .stages import WindowEstimator

if TYPE_CHECKING:
    from ..formats.mcaplog.recorder import McapRecorder
    from .sources import Source
    from .zenoh_bus import ZenohBus

__all__ = ["Pipeline", "StageStats", "CompensatorHook", "Compensator", "Message"]

log = logging.getLogger("hystbench.pipeline")
_TOPIC_NAMES = {ESTIMATE: "estimate", COMPENSATOR: "compensator", STATUS: "status", STATS: "stats"}


class _SwitchInterval:
    """The interpreter's thread switch interval is one setting for the process: the first pipeline to
    lower it keeps what it was, the last one to finish puts that back (two pipelines whose lives
    overlap used to leave the lowered value behind, the second having saved the first's)."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._holders = 0
        self._original = 0.0

    def lower(self, to_s: float | None) -> None:
        with self._lock:
            if self._holders == 0:
                self._original = sys.getswitchinterval()
            self._holders += 1
            if to_s is not None and sys.getswitchinterval() > to_s:
                sys.setswitchinterval(to_s)

    def release(self) -> None:
        with self._lock:
            self._holders -= 1
            if self._holders == 0:
                sys.setswitchinterval(self._original)


_SWITCH = _SwitchInterval()


@runtime_checkable
class Message(Protocol):
    """A typed message (:class:`~hystbench.messages.Estimate`): it knows its JSON."""

    def to_json(self) -> dict[str, Any]: ...


@runtime_checkable
class Compensator(Protocol):
    """What :class:`CompensatorHook` drives (the pipeline knows a compensator only by this).

    ``update(estimate)`` returns a :class:`~hystbench.messages.CompensatorUpdate` (its ``state``, a
    JSON-able mapping, is published on ``compensator``; ``output_off`` and ``waveform_a`` are what
    the hook does to the source) or None.  One whose ``learns`` attribute is true is called
    ``update(estimate, window)`` with the estimate's samples (a :class:`SampleBlock`)."""

    def update(self, estimate: Estimate, window: SampleBlock | None = None) -> CompensatorUpdate | None: ...


@dataclass
class StageStats:
    """Counters of one stage; latencies (ms, from a block's arrival) kept for the last 4096."""

    name: str
    blocks: int = 0
    samples: int = 0
    lost_samples: int = 0
    dropped_messages: int = 0
    errors: int = 0
    busy_s: float = 0.0
    waited_s: float = 0.0  # a lossless source, held back by the slowest stage
    latencies_ms: deque = field(default_factory=lambda: deque(maxlen=4096))
    started: float = field(default_factory=time.monotonic)

    def as_dict(self) -> dict[str, Any]:
        lat = np.asarray(self.latencies_ms) if self.latencies_ms else np.zeros(1)
        up = max(time.monotonic() - self.started, 1e-9)
        return {"blocks": self.blocks, "samples": self.samples, "samples_per_s": self.samples / up,
                "lost_samples": self.lost_samples, "dropped_messages": self.dropped_messages,
                "errors": self.errors, "busy_fraction": self.busy_s / up,
                "waited_fraction": self.waited_s / up,
                "latency_ms_p50": float(np.percentile(lat, 50)), "latency_ms_p99": float(np.percentile(lat, 99)),
                "latency_ms_max": float(lat.max())}


#: The most memory a pipeline's ring may take (2 s of 4 channels of float32 at 16 MS/s each: 0.5 GiB).
MAX_RING_BYTES = 2 * 2**30


class Pipeline:
    """Runs a source through the ring to the estimator, the recorder and the bus.

    ``recorder`` is a started :class:`~.mcaplog.McapRecorder` (or None), ``bus`` an open
    :class:`~.zenoh_bus.ZenohBus` (or None), ``estimator`` a :class:`WindowEstimator` (or None),
    ``compensator`` a callable (estimate, window) -> state (e.g. :class:`CompensatorHook`); the
    window is the estimate's samples (a :class:`SampleBlock`) when the estimator keeps them, else
    None.  ``lossless`` (default: whether the source's ``pace`` is ``"max"``) makes the source
    wait for the slowest stage instead of overrunning it; ``backpressure`` is set while it waits.
    """

    def __init__(self, source: Source, *, estimator: WindowEstimator | None = None,
                 recorder: McapRecorder | None = None, bus: ZenohBus | None = None,
                 compensator: Callable[[Estimate, SampleBlock | None], dict | None] | None = None,
                 ring_seconds: float = 2.0, dtype: DTypeLike = np.float32, queue_size: int = 1024,
                 stats_interval_s: float = 1.0, publish_raw: bool = True,
                 gil_switch_s: float | None = 0.0005, background_nice: int = 10,
                 lossless: bool | None = None, on_log_error: Callable[[LogWriteError], None] | None = None,
                 epoch_ns: int | None = None) -> None:
        self.source, self.estimator, self.recorder, self.bus = source, estimator, recorder, bus
        self.on_log_error = on_log_error
        self.log_error: LogWriteError | None = None  # why the recorder was let go, if it was
        #: the log's clock (wall time of sample 0), kept when a recorder is let go or attached
        self.epoch_ns = epoch_ns if epoch_ns is not None else recorder.epoch_ns if recorder is not None else None
        self.lossless = getattr(source, "pace", None) == "max" if lossless is None else bool(lossless)
        self.backpressure = threading.Event()  # set while a lossless source waits for a stage
        self.compensator = compensator
        self.publish_raw = publish_raw
        self.gil_switch_s = gil_switch_s
        self.background_nice = background_nice
        self.stats_interval_s = stats_interval_s
        cap = max(int(ring_seconds * source.fs_hz), 1024)
        ring_bytes = cap * len(source.channels) * np.dtype(dtype).itemsize
        if ring_bytes > MAX_RING_BYTES:  # asked of numpy, it was a 29.8 GiB MemoryError and a stray log
            raise ConfigError(f"{source.name}: a ring of {ring_seconds:g} s at {source.fs_hz:g} S/s x "
                              f"{len(source.channels)} channels is {ring_bytes / 2**30:.1f} GiB, more than the "
                              f"{MAX_RING_BYTES / 2**30:g} GiB a pipeline holds; lower the sample rate (or ring_seconds)")
        self.ring = RingBuffer(source.channels, cap, fs_hz=source.fs_hz, dtype=dtype)
        self.listeners: list[Callable[[str, Mapping[str, Any]], None]] = []
        #: called with each source block in the source thread, after the ring has it: each must only
        #: hand it on (a bounded queue, drop when full), e.g. the daemon's Foxglove view; one that
        #: raises is logged and counted (``publish`` errors), never fatal
        self.block_listeners: list[Callable[[SampleBlock], None]] = []
        self.stats = {n: StageStats(n) for n in ("source", "estimate", "record", "publish")}
        self._arr_pos = np.zeros(8192, dtype=np.int64)  # ring end position of each source block...
        self._arr_t = np.zeros(8192)  # ...and its monotonic arrival time (a circular log)
        self._n_arrivals = 0
        #: the source's sample index one past the last block written to the ring (None: no block
        #: yet); its own sample clock, however fast or slow it runs against the wall clock
        self.position: int | None = None
        self.last_meta: Mapping[str, Any] = {}  # that block's meta: the operating point it was played at
        self._index_waits: list[list] = []  # [index or None (from the first block), n, Event]
        self._index_lock = threading.Lock()
        self._queue: queue.Queue = queue.Queue(queue_size)
        self._stop = threading.Event()
        self._source_done = threading.Event()
        self._stop_by = Deadline(None)  # how long the log waits for the estimator once stopped
        self._threads: list[threading.Thread] = []
        self._readers: dict[str, RingReader] = {}
        self.error: BaseException | None = None
        self.finished = threading.Event()
        self._holds_switch = False
        self._running = 0  # threads not yet ended: the last one gives the switch interval back
        self._running_lock = threading.Lock()

    # --- life cycle ------------------------------------------------------------------------------
    def start(self) -> "Pipeline":
        """Start the threads.  ``gil_switch_s`` (default 0.5 ms) lowers the interpreter's thread switch
        interval (5 ms by default, process-wide): a stage busy in Python then holds the source
        thread up for at most that long, which is what keeps the raw-data latency in milliseconds.
        The estimate and record threads run at ``background_nice`` (Linux thread niceness), so on a
        busy core the scheduler runs the source thread first."""
        _SWITCH.lower(self.gil_switch_s)  # process-wide: given back when the last pipeline's threads end
        self._holds_switch = True
        if self.estimator is not None:
            self._readers["estimate"] = self.ring.reader("estimate")
        if self.recorder is not None:
            self._readers["record"] = self.ring.reader("record")
        plan = [("source", self._run_source), ("stats", self._run_stats)]
        if self.estimator is not None:
            plan.append(("estimate", self._run_estimate))
        if self.recorder is not None:
            plan.append(("record", self._run_record))
        for name, target in plan:
            t = threading.Thread(target=self._guard, args=(name, target), name=f"pipeline-{name}", daemon=True)
            self._threads.append(t)
        self._running = len(self._threads)
        for t in self._threads:
            t.start()
        self.status("info", "started", f"pipeline on {self.source.name}")
        return self

    def stop(self, timeout_s: float = 10.0) -> None:
        """Stop the source, let the readers drain the ring, stop every thread (bounded wait; the
        log waits for the estimator's last estimates for 80 % of it at most)."""
        self._stop_by = Deadline(0.8 * timeout_s)
        self._stop.set()
        self.join(timeout_s)

    def join(self, timeout_s: float | None = None) -> bool:
        """Wait until the source ended and every reader drained; True if all threads finished.
        The estimator is waited for last: what the log needs (the source, the record stage) first."""
        deadline = Deadline(timeout_s)  # one bound for all the threads, not timeout_s each
        for t in sorted(self._threads, key=lambda t: t.name == "pipeline-estimate"):
            t.join(deadline.left())
        done = not any(t.is_alive() for t in self._threads)
        if done:
            self.finished.set()
        return done

    def _guard(self, name: str, target: Callable[[], None]) -> None:
        if name in ("estimate", "record") and self.background_nice:
            try:  # Linux: per-thread nice; the source thread (raw data, zenoh) goes first on a busy core
                os.setpriority(os.PRIO_PROCESS, threading.get_native_id(), self.background_nice)
            except (AttributeError, OSError):
                pass
        try:
            target()
        except BaseException as err:  # a stage that dies takes the pipeline down, visibly
            log.exception("pipeline stage %s failed", name)
            self.error = self.error or err
            self.stats.get(name, self.stats["source"]).errors += 1
            self._stop.set()
            self.ring.close()
            self._source_done.set()
        finally:
            self._thread_ended()

    def _thread_ended(self) -> None:
        """The last thread to end gives the switch interval back, whether or not anyone joins the
        pipeline (one left unjoined used to keep it lowered for the rest of the process)."""
        with self._running_lock:
            self._running -= 1
            release = self._running == 0 and self._holds_switch
            if release:
                self._holds_switch = False
        if release:
            _SWITCH.release()

    # --- messages --------------------------------------------------------------------------------
    def emit(self, topic: str, message: Mapping[str, Any] | Message) -> None:
        """``message`` (a dict, or a typed message turned into its JSON here) to the recorder, the
        bus and the listeners."""
        obj = message if isinstance(message, Mapping) else message.to_json()
        if self.recorder is not None:
            try:
                self._queue.put_nowait((topic, dict(obj)))
            except queue.Full:
                self.stats["record"].dropped_messages += 1
        if self.bus is not None:
            self.bus.publish(_TOPIC_NAMES.get(topic, topic.strip("/")), obj)
        for fn in list(self.listeners):
            try:
                fn(topic, obj)
            except Exception:
                log.exception("listener failed on %s", topic)

    def status(self, level: str, event: str, message: str = "", **extra: Any) -> None:
        log.log(logging.WARNING if level == "warning" else logging.ERROR if level == "error" else logging.INFO,
                "%s: %s", event, message)
        self.emit(STATUS, {"t_ns": time.time_ns(), "level": level, "event": event, "message": message, **extra})

    def index_time_ns(self, index: int) -> int:
        """Log time of a sample index (the recorder's clock, or ns from sample 0 without one)."""
        return (self.epoch_ns or 0) + round(index * 1e9 / self.source.fs_hz)

    # --- threads ---------------------------------------------------------------------------------
    def _run_source(self) -> None:
        st, pub = self.stats["source"], self.stats["publish"]
        dtype = self.ring.dtype
        try:
            for block in self.source.blocks(self._stop):
                t_in = time.monotonic()
                if any(x.dtype != dtype for x in block.channels.values()):
                    block = SampleBlock(block.first_index, block.fs_hz,
                                        {k: np.asarray(v, dtype=dtype) for k, v in block.channels.items()},
                                        flags=block.flags, gap_samples=block.gap_samples, meta=block.meta)
                if self.bus is not None and self.publish_raw:  # first: subscribers wait for nothing else
                    self.bus.publish_block(block)
                    now = time.monotonic()
                    pub.blocks += 1
                    pub.samples += block.n
                    pub.busy_s += now - t_in
                    pub.latencies_ms.append(1e3 * (now - t_in))
                t0, waited = time.monotonic(), 0.0
                k = self._n_arrivals % self._arr_pos.size  # logged first: a reader that sees the
                self._arr_pos[k], self._arr_t[k] = self.ring.head + block.n, t_in  # samples finds it
                self._n_arrivals += 1
                if self.lossless:
                    waited = self._write_waiting(block)
                    if waited is None:
                        break
                    st.waited_s += waited
                else:
                    self.ring.write(block)
                self._arrived_at(block)
                for fn in self.block_listeners:
                    try:
                        fn(block)
                    except Exception:
                        pub.errors += 1
                        log.exception("block listener failed at sample %d", block.first_index)
                st.blocks += 1
                st.samples += block.n
                now = time.monotonic()
                st.busy_s += now - t0 - waited
                st.latencies_ms.append(1e3 * (now - t_in))
                if self._stop.is_set():
                    break
        finally:
            self.ring.close()
            self._source_done.set()

    def after_samples(self, n: int) -> threading.Event:
        """An Event set once the source has given ``n`` samples past :attr:`position` now (past
        its first sample if it has given none yet): waits that count the source's samples, not
        wall time (a sweep's dwell).  It is never set if the source ends or stalls first."""
        ev = threading.Event()
        with self._index_lock:
            target = None if self.position is None else self.position + int(n)
            if target is not None and n <= 0:
                ev.set()
            else:
                self._index_waits.append([target, int(n), ev])
        return ev

    def _arrived_at(self, block: SampleBlock) -> None:
        """Move :attr:`position` to the end of ``block`` and set the waits it reached."""
        with self._index_lock:
            self.position, self.last_meta = block.end_index, block.meta
            if self._index_waits:
                for w in self._index_waits:
                    if w[0] is None:
                        w[0] = block.first_index + w[1]
                    if w[0] <= block.end_index:
                        w[2].set()
                self._index_waits = [w for w in self._index_waits if not w[2].is_set()]

    def _write_waiting(self, block: SampleBlock) -> float | None:
        """Write ``block`` once every reader has room for it (in pieces of at most half the ring);
        the seconds it waited, or None if the pipeline stopped or the ring closed (a stage died)
        while it waited."""
        step = max(1, self.ring.capacity // 2)
        waited = 0.0
        for k in range(0, block.n, step):
            piece = block if block.n <= step else SampleBlock(
                block.first_index + k, block.fs_hz, {c: x[k:k + step] for c, x in block.channels.items()},
                flags=block.flags if k == 0 else block.flags & ~BlockFlags.GAP,
                gap_samples=block.gap_samples if k == 0 else 0, meta=block.meta)
            if not self.ring.wait_for_room(piece.n, timeout_s=0.0):
                self.backpressure.set()
                t_wait = time.monotonic()
                while not self.ring.wait_for_room(piece.n, timeout_s=0.1):
                    if self._stop.is_set() or self.ring.closed:
                        self.backpressure.clear()
                        return None
                waited += time.monotonic() - t_wait
                self.backpressure.clear()
            self.ring.write(piece)
        return waited

    def _block_end(self, pos: int) -> int | None:
        """Ring position where the source block holding position ``pos`` ends (None: not logged
        yet, or already forgotten)."""
        n, m = self._n_arrivals, self._arr_pos.size
        lo, hi = max(0, n - m), n - 1
        if hi < lo or self._arr_pos[hi % m] <= pos or (n > m and self._arr_pos[lo % m] > pos):
            return None  # the block is not logged yet, or its end was forgotten
        while lo < hi:  # the first block ending after pos
            mid = (lo + hi) // 2
            if self._arr_pos[mid % m] > pos:
                hi = mid
            else:
                lo = mid + 1
        return int(self._arr_pos[lo % m])

    def _arrived(self, end_pos: int) -> float | None:
        """Arrival time of the source block holding ring position ``end_pos - 1`` (a binary search
        over the last arrivals; a racing write can at worst skew one latency sample)."""
        n, m = self._n_arrivals, self._arr_pos.size
        lo, hi = max(0, n - m), n - 1
        if hi < lo or self._arr_pos[hi % m] < end_pos:
            return None
        while lo < hi:  # the first block ending at or after end_pos
            mid = (lo + hi) // 2
            if self._arr_pos[mid % m] >= end_pos:
                hi = mid
            else:
                lo = mid + 1
        return float(self._arr_t[lo % m])

    def _latency(self, st: StageStats, end_pos: int) -> None:
        t = self._arrived(end_pos)
        if t is not None:
            st.latencies_ms.append(1e3 * (time.monotonic() - t))

    def _run_estimate(self) -> None:
        st, r, est = self.stats["estimate"], self._readers["estimate"], self.estimator
        while True:
            got = r.read(timeout_s=0.2)
            if got is None:
                if self.ring.closed and r.lag <= 0:
                    return
                continue
            t0 = time.monotonic()
            if got.lost:  # lapped before this read: the estimator's run restarts after the gap
                self.status("warning", "estimator_overrun", f"estimation lost {got.lost} samples before sample "
                            f"{got.block.first_index}")
            est.append(got.block)
            if not r.release(got):  # lapped while copying: what was copied may be torn
                est.reset()
                est.windowed()  # and so may the windows just cut from it: dropped
                self.status("warning", "estimator_overrun", f"estimation lost {got.n} samples at {got.block.first_index}")
            st.lost_samples = r.lost_samples
            st.blocks += 1
            st.samples += got.n
            for e, window in est.windowed():  # the window: samples for a learning compensator, never published
                e = replace(e, t_ns=self.index_time_ns(e.end_index))
                if e.outliers:
                    from ..analysis.method import outlier_summary

                    found = {c: list(v) for c, v in e.outliers.items()}
                    self.status("warning", "outliers", f"window [{e.first_index}..{e.end_index}): left out "
                                f"{outlier_summary(found)}", outliers=found)
                self.emit(ESTIMATE, e)
                if self.compensator is not None:
                    state = self.compensator(e, window)
                    if state:
                        self.emit(COMPENSATOR, {"t_ns": e.t_ns, "first_index": e.first_index, **state})
            st.busy_s += time.monotonic() - t0
            self._latency(st, got.end)

    def _drain_messages(self, rec: McapRecorder) -> None:
        while True:
            try:
                topic, obj = self._queue.get_nowait()
            except queue.Empty:
                return
            rec.add_message(topic, obj, obj.get("t_ns"))

    def _read_source_blocks(self, r: RingReader) -> list[RingRead]:
        """The next source block (or what is left of it), cut where the source cut it and joined
        again where the ring's wrap point split it (copied: the views are not contiguous there).
        A plain read when the block's end is not known; two reads if the ring lapped in between."""
        end = self._block_end(r.cursor)
        cap = self.ring.capacity
        if end is None or r.cursor // cap == (end - 1) // cap:
            got = r.read(None if end is None else end - r.cursor)
            return [] if got is None else [got]
        parts: list[RingRead] = []
        while (not parts or parts[-1].end < end) and r.lag > 0:
            more = r.read(end - r.cursor, copy=True)
            if more is None:
                break
            if parts and (more.lost or more.block.first_index != parts[-1].block.end_index):
                return [self._joined(parts), more]  # lapped in between (live): the rest comes as it is
            parts.append(more)
        return [self._joined(parts)] if parts else []

    @staticmethod
    def _joined(parts: list[RingRead]) -> RingRead:
        if len(parts) == 1:
            return parts[0]
        b = parts[0].block
        block = SampleBlock(b.first_index, b.fs_hz, {c: np.concatenate([p.block.channels[c] for p in parts])
                                                     for c in b.channels},
                            flags=b.flags, gap_samples=b.gap_samples, meta=b.meta)
        return RingRead(block, parts[0].lost, parts[0].start, parts[-1].end)

    def attach_recorder(self, recorder: McapRecorder) -> None:
        """Start logging into ``recorder`` (started) from the newest sample on: after a write error
        let the last one go, once the disk has room again."""
        if self.recorder is not None:
            raise ConfigError("the pipeline already logs; it takes a recorder only after it let the last one go")
        self._readers["record"] = self.ring.reader("record", start="newest")
        self.recorder, self.log_error = recorder, None
        t = threading.Thread(target=self._guard, args=("record", self._run_record), name="pipeline-record", daemon=True)
        self._threads.append(t)
        t.start()

    def _run_record(self) -> None:
        rec, r = self.recorder, self._readers["record"]
        try:
            self._record(rec, r)
        except LogWriteError as err:  # the disk's fault, not the pipeline's: everything else goes on
            self.ring.remove_reader(r)
            self.recorder = None
            rec.abandon()
            self.log_error = err
            self.status("error", "log_write_failed", f"{err}; logging stopped", folder=err.folder)
            if self.on_log_error is not None:
                self.on_log_error(err)

    def _record(self, rec: McapRecorder, r: RingReader) -> None:
        st = self.stats["record"]
        estimating = [t for t in self._threads if t.name == "pipeline-estimate"]
        last_lost = 0
        while True:
            reads = self._read_source_blocks(r) if r.wait(0.1) else []
            t0 = time.monotonic()
            for got in reads:
                rec.add_block(got.block)
                st.blocks += 1
                st.samples += got.n
                if r.lost_samples != last_lost:
                    self.status("warning", "recorder_overrun", f"recorder lost {r.lost_samples - last_lost} "
                                f"samples before sample {got.block.first_index}")
                    last_lost = st.lost_samples = r.lost_samples
            self._drain_messages(rec)
            rec.tick()
            st.busy_s += time.monotonic() - t0
            if reads:
                self._latency(st, reads[-1].end)
            elif self.ring.closed and r.lag <= 0:
                # its last estimates are queued once it ended; stopped, the log waits for them only
                # until the stop's deadline (an estimator far behind held a daemon's SIGTERM past its
                # bound, and the log was left without its footer)
                if not any(t.is_alive() for t in estimating) or self._stop_by.expired:
                    if any(t.is_alive() for t in estimating):
                        log.warning("stopping: the log is finished without the estimates still being made "
                                    "(the estimator is %d samples behind)", self._readers["estimate"].lag
                                    if "estimate" in self._readers else 0)
                    self._drain_messages(rec)
                    rec.add_message(STATS, self.stats_dict())
                    return
                time.sleep(0.01)

    def _run_stats(self) -> None:
        while not self._source_done.wait(self.stats_interval_s):
            self.emit(STATS, self.stats_dict())

    def stats_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {"t_ns": time.time_ns(), "ring_samples": self.ring.capacity,
                               "stages": {k: v.as_dict() for k, v in self.stats.items()}}
        out["readers_lag"] = {k: r.lag for k, r in self._readers.items()}
        if self.bus is not None:
            out["zenoh_put_errors"] = self.bus.put_errors
        if self.recorder is not None:
            out["mcap_bytes"] = self.recorder.bytes_written
        return out


class CompensatorHook:
    """Hands each estimate to the compensator (a :class:`Compensator`) and applies what it asks for.

    A compensator that ``learns`` also gets each estimate's samples: the estimator must keep them
    (``wants_windows``).  If the :class:`~hystbench.messages.CompensatorUpdate` it returns says
    ``output_off`` the source's output goes off before anything else; if it carries ``waveform_a``
    (one period of current, uniformly sampled), the waveform is uploaded to the source (a
    :class:`Controllable`) at its ``frequency_hz`` (else the estimate's).  What is published is
    the update's ``state`` with what was done added (``output_switched_off``,
    ``waveform_applied``).  After an output off, ``tripped`` says why, and the daemon refuses to
    switch the output on again until it is reloaded.  A compensator that raises, or returns
    anything but an update or None, is reported, never fatal.
    """

    def __init__(self, compensator: Compensator, source: Any = None) -> None:
        if not callable(getattr(compensator, "update", None)):
            raise ConfigError(f"compensator {compensator!r} has no update(estimate) method")
        self.compensator, self.source = compensator, source
        self.wants_windows = bool(getattr(compensator, "learns", False))
        self.errors = 0
        self.last_error = ""
        self.tripped = ""  # why the compensator switched the output off (then it stays off)

    def __call__(self, estimate: Estimate, window: SampleBlock | None = None) -> dict | None:
        if estimate.error:
            return None
        try:
            if self.wants_windows and window is not None:
                update = self.compensator.update(estimate, window)
            else:
                update = self.compensator.update(estimate)
            if update is not None and not isinstance(update, CompensatorUpdate):
                raise TypeError(f"update() returned a {type(update).__name__}, not a "
                                "hystbench.messages.CompensatorUpdate (or None)")
        except Exception as err:  # the compensator is someone else's code: report, carry on
            self.errors += 1
            self.last_error = f"{type(err).__name__}: {err}"
            return {"error": self.last_error, "first_index": estimate.first_index}
        if update is None or not (update.state or update.output_off or update.waveform_a is not None):
            return None
        state = dict(update.state)
        if update.output_off:
            self.tripped = str(state.get("status") or "the compensator asked for the output off")
            if isinstance(self.source, Controllable):
                self.source.set_output(False)
                state["output_switched_off"] = True
        if update.waveform_a is not None and isinstance(self.source, Controllable):
            f = estimate.nominal_frequency_hz if update.frequency_hz is None else update.frequency_hz
            try:
                self.source.set_waveform(update.waveform_a, float(f))
                state["waveform_applied"] = True
            except (ConfigError, CommandRefused) as err:  # beyond the bench's limits (or busy): a trip, not a fault
                self.source.set_output(False)
                self.tripped = f"its waveform was refused ({err})"
                state.update(output_switched_off=True, waveform_refused=str(err))
        return state
