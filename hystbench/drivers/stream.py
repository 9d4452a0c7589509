"""Sample streams: frames from a transport turned into :class:`SampleBlock` s with exact gaps.

A background reader (one per stream) pulls frames from a :class:`FrameSource` (TCP with length
prefixes, serial with COBS, CAN FD), checks their first-sample index against the last one kept and
queues contiguous runs.  ``read(timeout_s)`` hands them out as blocks; a block after missing samples
has ``BlockFlags.GAP`` and ``gap_samples`` = exactly how many indices are missing, however many
frames were lost or damaged.  A silent or dropped transport is reopened with back-off; when the
attempts run out, or an instrument that takes every reconnection stays silent for ``lost_after_s``,
``read`` raises ``ConnectionLost``.
"""

from __future__ import annotations

import abc
import collections
import socket
import threading
import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Iterator, Mapping, Sequence

import numpy as np

from ..blocks import BlockFlags, SampleBlock
from ..deadline import Deadline
from ..errors import ConnectionLost, InstrumentError
from .base import Backoff, log
from .protocols import can_stream
from .protocols.framing import (
    CobsDeframer, DeframerStats, Frame, FrameBatch, FrameError, LengthPrefixDeframer, warm_cobs, warm_crc_rows)

if TYPE_CHECKING:
    import can

__all__ = ["FrameSource", "TcpFrameSource", "SerialFrameSource", "CanFrameSource", "StreamStats",
           "SampleStream", "parse_stream_url"]

_TCP_READ = 1 << 18  # bytes asked of one recv
_SERIAL_READ = 1 << 18
_LIVE_HISTORY = 256  # drained reads remembered per stream (a few seconds of them at the live edge)

#: A stream silent this long, through every reconnection, is given up (``ConnectionLost``): an
#: instrument that takes the connection and sends nothing would be retried for ever, the daemon
#: "running" with no sample.  Counted in time, not in reconnections: a starved test machine held
#: the emulated streams silent through six 0.7 s reconnections and they came back (CI, 2026-11-30).
LOST_AFTER_S = 20.0


def parse_stream_url(url: str) -> tuple[str, str]:
    """'tcp://host:port' -> ('tcp', 'host:port'); anything else is a serial URL or device path."""
    if url.startswith("tcp://"):
        return "tcp", url[len("tcp://"):]
    return "serial", url


def frame_source(url: str, stream_id: int, channels: int = 1) -> "FrameSource":
    """The frame source a stream URL names: length-prefixed frames over TCP, or COBS over serial."""
    kind, where = parse_stream_url(url)
    if kind == "tcp":
        return TcpFrameSource(where, stream_id=stream_id, channels=channels)
    return SerialFrameSource(where, stream_id=stream_id, channels=channels)


class FrameSource(abc.ABC):
    """Where frames come from.  ``read_frames`` waits at most ``timeout_s``; transport loss raises.

    ``drained`` is True after a read that took everything the transport held when it looked (the
    reader was at the live edge): samples the instrument made before that moment are all in, bar
    what was still on the wire.  It is how a command's first sample is bounded when the reader has
    fallen behind (:meth:`SampleStream.live_index_after`).  A source that cannot tell leaves it
    False: then no command's first sample is ever known, and what follows a command stays marked
    settling (safe, not silent)."""

    name: str = "stream"
    deframer_stats: DeframerStats
    drained: bool = False
    seq_modulus: int = 1 << 32  #: where the frames' sequence numbers wrap

    @abc.abstractmethod
    def open(self) -> None: ...

    @abc.abstractmethod
    def close(self) -> None: ...

    @abc.abstractmethod
    def read_frames(self, timeout_s: float) -> list[Frame | FrameBatch]: ...

    def warm(self) -> None:
        """Make ready what ``read_frames`` compiles on first use (before the transport opens, so no
        backlog builds meanwhile)."""


class TcpFrameSource(FrameSource):
    """Length-prefixed frames from a TCP port (``host:port``), the instruments' LAN stream ports."""

    def __init__(self, address: str, *, stream_id: int | None = None, channels: int | None = None,
                 connect_timeout_s: float = 1.0) -> None:
        host, _, port = address.rpartition(":")
        self.address, self.host, self.port = address, host, int(port)
        self._ids = (stream_id, channels)
        self.connect_timeout_s = connect_timeout_s
        self._sock: socket.socket | None = None
        self.deframer = LengthPrefixDeframer(*self._ids)
        self.deframer_stats = self.deframer.stats

    def open(self) -> None:
        self.close()
        self._sock = socket.create_connection((self.host, self.port), timeout=self.connect_timeout_s)
        self._sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 20)
        stats = self.deframer.stats
        self.deframer = LengthPrefixDeframer(*self._ids)  # a new connection starts on a boundary
        self.deframer.stats = self.deframer_stats = stats

    def close(self) -> None:
        if self._sock is not None:
            self._sock.close()
            self._sock = None

    def read_frames(self, timeout_s: float) -> list[Frame]:
        if self._sock is None:
            raise ConnectionError(f"{self.address} is not open")
        self._sock.settimeout(timeout_s)
        try:
            data = self._sock.recv(_TCP_READ)
        except socket.timeout:
            self.drained = True
            return []
        if not data:
            raise ConnectionError(f"{self.address}: peer closed the stream")
        self.drained = len(data) < _TCP_READ  # recv hands over what is queued: less than asked is all of it
        return self.deframer.feed(data)


class SerialFrameSource(FrameSource):
    """COBS frames from a serial port (or any pyserial URL): a stream with no framing of its own."""

    def __init__(self, url: str, *, stream_id: int | None = None, channels: int | None = None,
                 baudrate: int = 115200) -> None:
        self.url, self.baudrate = url, baudrate
        self._port = None
        self._opened = False
        self.deframer = CobsDeframer(stream_id, channels)
        self.deframer_stats = self.deframer.stats

    def warm(self) -> None:
        warm_cobs()

    def open(self) -> None:
        """The first open drops what the line held before (another session's bytes); a reopen
        (after a stall or a lost port) keeps the bytes waiting and the deframer's place, so that a
        line that was only quiet loses nothing (a line that really restarted costs one bad record)."""
        import serial

        self.close()
        self._port = serial.serial_for_url(self.url, baudrate=self.baudrate, timeout=0.05)
        if not self._opened:
            self._port.reset_input_buffer()
            self.deframer.resync()
            self._opened = True

    def close(self) -> None:
        if self._port is not None:
            self._port.close()
            self._port = None

    def read_frames(self, timeout_s: float) -> list[Frame]:
        """What came within ``timeout_s``: the bytes waiting, or (none waiting) the first byte to come
        and the burst that came with it, so a burst is one call, not a byte then the rest."""
        port = self._port
        if port is None:
            raise ConnectionError(f"{self.url} is not open")
        if port.timeout != timeout_s:  # pyserial reconfigures the port (tcgetattr, tcsetattr) on every set
            port.timeout = timeout_s
        waiting = port.in_waiting
        data = port.read(min(waiting, _SERIAL_READ) if waiting else 1)
        if data and not waiting and (waiting := port.in_waiting):
            data += port.read(min(waiting, _SERIAL_READ))
        self.drained = waiting <= _SERIAL_READ  # everything that was waiting when it looked was read
        return self.deframer.feed(data) if data else []


class CanFrameSource(FrameSource):
    """CAN FD: one stream frame (``protocols.can_stream``: 17 samples of 24 bits) per CAN message
    with the stream's arbitration id; other messages are ignored."""

    max_batch = 256  #: messages drained per read: one decode amortised over them, the reader never starved
    seq_modulus = can_stream.SEQ_MODULUS

    def __init__(self, bus: can.BusABC, can_id: int, *, stream_id: int, open_timeout_s: float = 0.2) -> None:
        self.bus, self.can_id, self.stream_id = bus, can_id, stream_id
        self.open_timeout_s = open_timeout_s
        self.deframer_stats = DeframerStats()
        self._pending: list[Frame | FrameBatch] = []
        self._opened = False

    def warm(self) -> None:
        warm_crc_rows()

    def open(self) -> None:
        """A CAN bus has no connection: reopening means frames of this stream are on the bus again."""
        if not self._opened:
            self._opened = True
            return
        self._pending = self.read_frames(self.open_timeout_s)
        if not self._pending:
            raise ConnectionError(f"no stream frames with CAN id 0x{self.can_id:x} "
                                  f"within {self.open_timeout_s:g} s")

    def close(self) -> None:
        self._pending = []

    def read_frames(self, timeout_s: float) -> list[Frame | FrameBatch]:
        """Drain up to ``max_batch`` messages of this stream (waiting for the first one only), then
        decode them together (:meth:`decode`)."""
        out, self._pending = self._pending, []
        deadline = Deadline(timeout_s)
        payloads: list[bytes | bytearray] = []
        recv, can_id, append, limit = self.bus.recv, self.can_id, payloads.append, self.max_batch
        wait = not out  # python-can's recv is the bound here (a Python call per message): keep the rest lean
        self.drained = False
        while len(payloads) < limit:
            msg = recv(deadline.left() if wait else 0.0)
            if msg is None:
                self.drained = True  # the bus's queue is empty
                break
            if msg.arbitration_id != can_id or msg.is_error_frame or msg.is_remote_frame:
                continue
            append(msg.data)  # python-can made the Message for this handle alone: no copy
            wait = False
        return out + self.decode(payloads)

    def decode(self, payloads: Sequence[bytes | bytearray]) -> list[Frame | FrameBatch]:
        """Message payloads (in arrival order) to what the stream accepts, damage counted: runs of
        full frames as :class:`FrameBatch` es, decoded together (:func:`can_stream.decode_frames`)."""
        out, refused = can_stream.decode_frames(payloads, self.stream_id)
        accepted = sum(len(x) if isinstance(x, FrameBatch) else 1 for x in out)
        stats = self.deframer_stats
        stats.frames += accepted
        if refused:
            stats.corrupt += refused
            stats.discarded_bytes += sum(map(len, payloads)) - accepted * can_stream.FRAME_BYTES
        return out

    def decode_each(self, payloads: Sequence[bytes | bytearray]) -> list[Frame]:
        """Message payloads to frames one by one: the reference :meth:`decode` equals."""
        out: list[Frame] = []
        for data in payloads:
            try:
                out.append(can_stream.decode_frame(data, self.stream_id))
            except FrameError:
                self.deframer_stats.corrupt += 1
                self.deframer_stats.discarded_bytes += len(data)
                continue
            self.deframer_stats.frames += 1
        return out


def _to_si(wire: np.ndarray, scale: float) -> np.ndarray:
    """Wire samples (float32) times ``scale`` in float64: one pass, the same numbers as
    ``wire.astype(np.float64) * scale`` (x * 1.0 is x, so a unit scale is only the cast)."""
    if scale == 1.0:
        return wire.astype(np.float64)
    return np.multiply(wire, scale, dtype=np.float64)


@dataclass
class StreamStats:
    """What one stream lost and why, counted, so a gap in the data can be traced to its cause."""

    frames: int = 0  #: frames kept
    frames_lost: int = 0  #: frames never seen, from the sequence numbers
    gap_samples: int = 0  #: sample indices never delivered (sum of every block's gap_samples)
    gaps: int = 0  #: blocks delivered with BlockFlags.GAP
    estimated_gaps: int = 0  #: of those, gaps whose size is an estimate (BlockFlags.GAP_ESTIMATED)
    estimated_gap_samples: int = 0  #: the part of gap_samples that is estimated
    stale_frames: int = 0  #: frames at or before the last index kept (duplicates), discarded
    reconnects: int = 0
    stalls: int = 0  #: times no frame came within stall_timeout_s
    overruns: int = 0  #: runs dropped because the consumer did not read (queue full)
    deframer: DeframerStats = field(default_factory=DeframerStats)

    def as_dict(self) -> dict:
        d = {k: v for k, v in self.__dict__.items() if k != "deframer"}
        d.update({f"deframer_{k}": v for k, v in self.deframer.__dict__.items()})
        return d


class _Runs:
    """Contiguous pieces collected by one ``_accept``: arrays listed, concatenated once per run at
    the end (concatenating per frame made a drain of n frames cost n^2 copies)."""

    def __init__(self) -> None:
        self._pieces: list[tuple[int, list[np.ndarray], int]] = []
        self._end: int | None = None

    def add(self, first: int, data: np.ndarray, flags: int) -> None:
        if self._pieces and self._end == first and self._pieces[-1][2] == flags:
            self._pieces[-1][1].append(data)
        else:
            self._pieces.append((first, [data], flags))
        self._end = first + data.shape[1]

    def finish(self) -> list[tuple[int, np.ndarray, int]]:
        return [(first, parts[0] if len(parts) == 1 else np.concatenate(parts, axis=1), flags)
                for first, parts, flags in self._pieces]


class SampleStream:
    """One instrument's samples: ``read(timeout_s)`` -> SampleBlock | None; iterable; context manager.

    ``channels`` names the frame's rows; ``scale`` maps a channel to the factor from wire units to
    SI (e.g. N/V for a charge amplifier's voltage).  ``skew_s`` is the instrument's known sampling
    delay on the common clock, recorded in each block's meta as ``skew_s.<channel>``.
    ``lost_after_s``: see :data:`LOST_AFTER_S`."""

    def __init__(self, name: str, source: FrameSource, channels: Sequence[str], fs_hz: float, *,
                 scale: Mapping[str, float] | None = None, skew_s: float = 0.0,
                 stall_timeout_s: float = 0.5, backoff: Backoff | None = None,
                 max_queued_samples: int = 2_000_000, lost_after_s: float = LOST_AFTER_S) -> None:
        self.name, self.source, self.channels, self.fs_hz = name, source, list(channels), float(fs_hz)
        self.scale = dict(scale or {})
        self.skew_s = float(skew_s)
        self.stall_timeout_s = stall_timeout_s
        self.lost_after_s = lost_after_s
        self.backoff = backoff or Backoff()
        self.max_queued_samples = max_queued_samples
        self.stats = StreamStats(deframer=source.deframer_stats)
        self._runs: collections.deque[tuple[int, np.ndarray, int]] = collections.deque()
        self._queued = 0
        self._cond = threading.Condition()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._error: InstrumentError | None = None
        self._next_index: int | None = None  # reader side: one past the last index kept
        self._next_seq: int | None = None
        self._delivered_end: int | None = None  # consumer side
        #: (monotonic time a read began, one past the last index kept after it) of reads that left
        #: the transport drained: the reader's live edge
        self._live: collections.deque[tuple[float, int]] = collections.deque(maxlen=_LIVE_HISTORY)

    # --- life cycle ------------------------------------------------------------------------------
    def start(self) -> "SampleStream":
        if self._thread is not None:
            return self
        self.source.warm()
        try:
            self.source.open()
        except OSError as err:
            raise ConnectionLost(f"{self.name}: cannot open sample stream: {err}") from err
        self._thread = threading.Thread(target=self._reader, name=f"stream-{self.name}", daemon=True)
        self._thread.start()
        return self

    def close(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
            self._thread = None
        try:
            self.source.close()
        except OSError:
            pass
        shutdown = getattr(self.source, "shutdown", None)  # a source that owns its handle
        if shutdown is not None:
            shutdown()

    def __enter__(self) -> "SampleStream":
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __iter__(self) -> Iterator[SampleBlock]:
        while True:
            block = self.read(timeout_s=self.stall_timeout_s * 4)
            if block is not None:
                yield block

    # --- consumer side ---------------------------------------------------------------------------
    def read(self, timeout_s: float = 1.0, max_samples: int | None = None) -> SampleBlock | None:
        """The next contiguous run (or None after ``timeout_s``); raises the reader's fatal error."""
        if timeout_s <= 0 and not self._runs:  # a look that finds nothing (the end of every drain):
            if self._error is not None:  # no deadline, no lock (a run appended meanwhile: the next look)
                raise self._error
            return None
        deadline = Deadline(timeout_s)
        with self._cond:
            while not self._runs:
                if self._error is not None:
                    raise self._error
                if deadline.expired:
                    return None
                self._cond.wait(deadline.left())
            first, data, flags = self._runs.popleft()
            if max_samples is not None and data.shape[1] > max_samples:
                self._runs.appendleft((first + max_samples, data[:, max_samples:], flags))
                data = data[:, :max_samples]
            self._queued -= data.shape[1]
        gap = 0 if self._delivered_end is None else first - self._delivered_end
        if gap > 0:
            flags |= BlockFlags.GAP
            self.stats.gaps += 1
            self.stats.gap_samples += gap
            if flags & BlockFlags.GAP_ESTIMATED:
                self.stats.estimated_gaps += 1
                self.stats.estimated_gap_samples += gap
        self._delivered_end = first + data.shape[1]
        chans = {ch: _to_si(data[i], self.scale.get(ch, 1.0)) for i, ch in enumerate(self.channels)}
        meta = {f"skew_s.{ch}": self.skew_s for ch in self.channels}
        return SampleBlock(first, self.fs_hz, chans, flags=BlockFlags(flags), gap_samples=max(gap, 0), meta=meta)

    def live_index_after(self, t: float) -> int | None:
        """An index at or past the instrument's sample clock at monotonic time ``t`` (bar what was
        on the wire then): where the first read that began at or after ``t`` and drained the
        transport left the stream.  None until such a read has happened.  However far the reader
        had fallen behind (a backlog in the socket, a starved thread), a sample past this index was
        made after ``t``."""
        for started, end in list(self._live):
            if started >= t:
                return end
        return None

    # --- reader side -----------------------------------------------------------------------------
    def _accept(self, items: Sequence[Frame | FrameBatch]) -> None:
        """Keep frames that extend the stream; merge contiguous ones into runs, each concatenated
        once (a frame at a time for :class:`Frame` s, vectorised for a :class:`FrameBatch`)."""
        runs = _Runs()
        for item in items:
            if isinstance(item, FrameBatch):
                self._accept_batch(item, runs)
            else:
                self._accept_frame(item, runs)
        pieces = runs.finish()
        if not pieces:
            return
        with self._cond:
            for p in pieces:
                self._runs.append(p)
                self._queued += p[1].shape[1]
            while self._queued > self.max_queued_samples and len(self._runs) > 1:
                _, dropped, _ = self._runs.popleft()  # the consumer will see the exact gap
                self._queued -= dropped.shape[1]
                self.stats.overruns += 1
            self._cond.notify_all()

    def _accept_frame(self, f: Frame, runs: "_Runs") -> None:
        """One frame: the rule :meth:`_accept_batch` vectorises (and must equal)."""
        first, data = f.first_index, f.samples
        if self._next_index is not None and first < self._next_index:
            if f.end_index <= self._next_index:
                self.stats.stale_frames += 1
                return
            data = data[:, self._next_index - first:]  # overlap: keep only what is new
            first = self._next_index
        if data.shape[0] != len(self.channels):
            self.stats.deframer.foreign += 1
            return
        mod = self.source.seq_modulus
        if self._next_seq is not None:  # frames never seen (informative; gaps come from indices)
            step = (f.seq - self._next_seq) % mod
            self.stats.frames_lost += step if step < mod // 2 else 0
        self._next_seq = (f.seq + 1) % mod
        self.stats.frames += 1
        self._next_index = first + data.shape[1]
        runs.add(first, data, f.flags)

    def _accept_batch(self, b: FrameBatch, runs: "_Runs") -> None:
        """:meth:`_accept_frame` on every row, vectorised.  A row is stale when it ends at or before
        the furthest end kept before it (every kept row ends past that, so it is the running maximum
        of the ends); a kept row starts at that end when it overlaps it."""
        k, c, n = b.samples.shape
        if k == 0:
            return
        end = b.first_index + n
        prev = self._next_index
        if c != len(self.channels):  # none is kept: stale against what was kept before, else foreign
            stale = 0 if prev is None else int(np.count_nonzero(end <= prev))
            self.stats.stale_frames += stale
            self.stats.deframer.foreign += k - stale
            return
        first, seq, flags, mod = b.first_index, b.seq, b.flags, self.source.seq_modulus
        if ((prev is None or first[0] >= prev) and np.array_equal(first[1:], first[:-1] + n)
                and np.array_equal(seq[1:], (seq[:-1] + 1) % mod) and not (flags != flags[0]).any()):
            # a healthy drain (what a bus that loses nothing gives): one run, nothing stale or overlapping
            if self._next_seq is not None:
                step = (int(seq[0]) - self._next_seq) % mod
                self.stats.frames_lost += step if step < mod // 2 else 0
            self._next_seq = (int(seq[-1]) + 1) % mod
            self.stats.frames += k
            self._next_index = int(end[-1])
            runs.add(int(first[0]), b.samples.transpose(1, 0, 2).reshape(c, k * n), int(flags[0]))
            return
        before = np.empty(k, dtype=np.int64)
        before[0] = np.iinfo(np.int64).min if prev is None else prev
        np.maximum.accumulate(end[:-1], out=before[1:])
        if prev is not None:
            np.maximum(before[1:], prev, out=before[1:])
        kept = end > before
        self.stats.stale_frames += k - int(np.count_nonzero(kept))
        rows = np.flatnonzero(kept)
        if rows.size == 0:
            return
        seq = b.seq[rows]
        expected = np.empty_like(seq)
        expected[1:] = (seq[:-1] + 1) % mod
        step = (seq - expected) % mod
        if self._next_seq is None:
            step = step[1:]
        else:
            step[0] = (seq[0] - self._next_seq) % mod
        self.stats.frames_lost += int(step[step < mod // 2].sum())
        self._next_seq = int(seq[-1] + 1) % mod
        self.stats.frames += rows.size
        self._next_index = int(end[rows[-1]])
        first, start, flags = first[rows], np.maximum(first[rows], before[rows]), flags[rows]
        # a new run where a row leaves a gap or changes flags; rows inside a run follow each other
        cut = (np.flatnonzero((start[1:] != before[rows[1:]]) | (flags[1:] != flags[:-1])) + 1).tolist()
        for lo, hi in zip([0, *cut], [*cut, rows.size]):
            trim = start[lo:hi] - first[lo:hi]
            if not trim.any():
                data = b.samples[rows[lo:hi]].transpose(1, 0, 2).reshape(c, (hi - lo) * n)
            else:  # overlapping rows: keep only what is new of each
                data = np.concatenate([b.samples[r][:, t:] for r, t in zip(rows[lo:hi], trim)], axis=1)
            runs.add(int(start[lo]), data, int(flags[lo]))

    def _reader(self) -> None:
        quiet = Deadline(self.stall_timeout_s)  # a stall: no frame before it passes
        heard = Deadline(self.lost_after_s)  # given up: no frame before it passes, however many reopens
        silent = 0  # succeeded since (an instrument that takes the connection and sends nothing)
        while not self._stop.is_set():
            started = time.monotonic()
            try:
                frames = self.source.read_frames(0.05)
            except (OSError, ValueError) as err:
                if not self._reopen(f"transport lost: {err}"):
                    return
                quiet = Deadline(self.stall_timeout_s)
                continue
            if frames:
                quiet, heard, silent = Deadline(self.stall_timeout_s), Deadline(self.lost_after_s), 0
                self._accept(frames)
            if self.source.drained and self._next_index is not None:
                self._live.append((started, self._next_index))
            if not frames and quiet.expired:
                self.stats.stalls += 1
                if heard.expired:
                    self._lost(f"(no frame for {self.lost_after_s:g} s through {silent} reconnections: the instrument "
                               "takes the connection and sends no samples)")
                    return
                silent += 1
                if not self._reopen(f"no frame for {self.stall_timeout_s:g} s"):
                    return
                quiet = Deadline(self.stall_timeout_s)

    def _reopen(self, why: str) -> bool:
        log.warning("%s: %s; reconnecting", self.name, why)
        try:
            self.source.close()
        except OSError:
            pass
        for delay in self.backoff.delays():
            if self._stop.wait(delay):
                return False
            try:
                self.source.open()
            except OSError as err:
                log.info("%s: reopen failed: %s", self.name, err)
                continue
            self.stats.reconnects += 1
            return True
        self._lost(f"({why}); {self.backoff.attempts} reconnection attempts failed")
        return False

    def _lost(self, why: str) -> None:
        """The stream is given up: ``read`` raises ConnectionLost saying why."""
        with self._cond:
            self._error = ConnectionLost(f"{self.name}: sample stream lost {why}")
            self._cond.notify_all()
