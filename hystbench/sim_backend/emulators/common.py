"""What every emulator needs: fault switches, a pseudo-terminal port, a TCP server, stream sinks.

Pseudo-terminals stand in for serial ports: the emulator holds the master, a driver opens the
slave path (``/dev/pts/N``).  The slave is put in raw mode and (but for a stream line's, below)
kept open here, so a driver can come and go without the port disappearing.  "Disconnect" on a
serial line is silence (a pulled cable); on TCP it closes the connections and refuses new ones
until ``reconnect``.

A serial stream line (:class:`PtyStreamSink`) is held like a real instrument's: what it sends
while no driver has the port open is lost (a real port that is not open drops what arrives), and
what it has not written yet is only the newest clock tick's samples, because the emulated bench
waits, before making a tick, until the last one's are on the line (:meth:`PtyStreamSink.wait_sent`).
A pseudo-terminal holds about 12 kB, less than a tick's burst, so the rest waits in the emulator,
where a driver's reader cannot see it: were it older than a tick, a reader that found the line
empty would place a command's first sample before samples made long before the command (the
drivers allow one tick in flight: ``BenchConfig.latency_s``).  What the pseudo-terminal holds is
on the line, as a real port's buffers are (``[bench] in_flight_s``).

Stream faults can be set to start at a sample index (``Faults.arm``, ``Faults.silence``) instead of
"from the next frame": what is dropped, damaged or silent is then fixed by the sample clock, not by
when a test thread happened to run, so the exact gap a receiver must report is known in advance.
"""

from __future__ import annotations

import collections
import errno
import functools
import logging
import os
import select
import socket
import threading
import time
import tty
import zlib
from dataclasses import dataclass, field
from typing import Callable, Iterator

import numpy as np

from ...drivers.protocols.framing import (MAGIC, MAX_FRAME_SIZE, OVERHEAD, VERSION, cobs_record, crc32_rows,
                                          encode_frame, frames_from_block, length_prefixed)
from ...drivers.protocols.scpi import SCPI_ERRORS, ScpiMessageReader

__all__ = ["Faults", "PtyPort", "TcpServer", "FrameEmitter", "TcpStreamServer", "PtyStreamSink", "encode_frames",
           "scpi_messages", "queue_scpi_error", "SCPI_QUEUE_MAX"]

log = logging.getLogger("hystbench.emulators")


@dataclass
class Faults:
    """Switchable faults of one emulator.  Counters are consumed one event at a time.

    A counter armed with ``arm(name, n, at_index=k)`` applies only to stream frames that start at
    or after sample ``k``; ``silence(k, n)`` makes the instrument silent (no frames, no replies)
    while its sample clock is in ``[k, k + n)``."""

    reply_delay_s: float = 0.0  #: slow replies
    drop_replies: int = 0  #: the next N replies are never sent (missing replies)
    garbage: bytes = b""  #: sent once on the command channel before the next reply
    drop_frames: int = 0  #: the next N stream frames are never sent
    corrupt_frames: int = 0  #: the next N stream frames get one flipped payload bit (bad CRC)
    stream_garbage: bytes = b""  #: bytes sent once on the stream before the next frame
    silent: bool = False  #: no replies, no frames (cable pulled / bus off / power loss)
    modbus_exception: int = 0  #: Modbus: exception code for the next requests (0 = none)
    modbus_exception_count: int = 0
    hold_replies: threading.Event | None = None  #: when given, every reply waits until it is set
    clock_index: int = 0  #: the sample clock's position (first index of the block being produced)
    replies_sent: int = 0  #: replies written to the command channel (tests wait on this)
    _from_index: dict = field(default_factory=dict, repr=False)
    _silent_span: tuple[int, int] | None = field(default=None, repr=False)
    _lock: threading.Lock = field(default_factory=threading.Lock, repr=False)
    _replies: threading.Condition = field(default_factory=threading.Condition, repr=False)

    def arm(self, name: str, value: int | bytes, *, at_index: int) -> None:
        """Set stream fault ``name`` (``drop_frames``, ``corrupt_frames``, ``stream_garbage``) for
        the frames from sample ``at_index`` on."""
        with self._lock:
            setattr(self, name, value)
            self._from_index[name] = int(at_index)

    def silence(self, first_index: int, n_samples: int) -> None:
        """No frames and no replies while the sample clock is in ``[first_index, first_index + n_samples)``."""
        with self._lock:
            self._silent_span = (int(first_index), int(first_index) + int(n_samples))

    def is_silent(self, index: int | None = None) -> bool:
        """Silent at sample ``index`` (default: where the clock is now)."""
        if self.silent:
            return True
        span = self._silent_span
        k = self.clock_index if index is None else index
        return span is not None and span[0] <= k < span[1]

    def _due(self, name: str, index: int | None) -> bool:
        start = self._from_index.get(name)
        return start is None or (index is not None and index >= start)

    def take(self, name: str, index: int | None = None) -> bool:
        """Consume one event of counter ``name`` (for a frame starting at ``index``); True if there was one."""
        with self._lock:
            left = getattr(self, name)
            if left > 0 and self._due(name, index):
                setattr(self, name, left - 1)
                if left == 1:
                    self._from_index.pop(name, None)
                return True
            return False

    def take_bytes(self, name: str, index: int | None = None) -> bytes:
        with self._lock:
            data = getattr(self, name)
            if not data or not self._due(name, index):
                return b""
            setattr(self, name, b"")
            self._from_index.pop(name, None)
            return data

    def stream_armed(self, first_index: int) -> bool:
        """Whether any stream fault could touch a frame from sample ``first_index`` on: only then
        does :class:`FrameEmitter` look at each frame (a quiet stream is encoded as one batch)."""
        span = self._silent_span
        return bool(self.silent or self.drop_frames or self.corrupt_frames
                    or (span is not None and span[1] > first_index))

    def before_reply(self) -> bool:
        """Apply the reply faults once a reply is ready; False if it is not to be sent."""
        if self.is_silent() or self.take("drop_replies"):
            return False
        hold = self.hold_replies
        if hold is not None:
            hold.wait(60.0)  # a reply held back on purpose, released by whoever holds it (not by time)
        if self.reply_delay_s:
            time.sleep(self.reply_delay_s)
        return True

    def sent_reply(self) -> None:
        with self._replies:
            self.replies_sent += 1
            self._replies.notify_all()

    def wait_replies(self, n: int, timeout_s: float) -> bool:
        """Wait until ``n`` replies in all have been written (True), or ``timeout_s`` passes."""
        with self._replies:
            return self._replies.wait_for(lambda: self.replies_sent >= n, timeout_s)

    def clear(self) -> None:
        with self._lock:
            self.reply_delay_s, self.drop_replies, self.garbage = 0.0, 0, b""
            self.drop_frames, self.corrupt_frames, self.stream_garbage = 0, 0, b""
            self.silent, self.modbus_exception, self.modbus_exception_count = False, 0, 0
            self.hold_replies, self._silent_span = None, None
            self._from_index.clear()


class PtyPort:
    """The emulator's end of a pseudo-terminal; ``path`` is what a driver opens.

    ``hold_slave=False`` (a stream line): the slave is not kept open here, so whether a driver has
    the port open can be told (:meth:`has_reader`); it keeps its raw mode for the next opener."""

    def __init__(self, max_pending: int = 1 << 20, *, hold_slave: bool = True) -> None:
        self.master, slave = os.openpty()
        tty.setraw(slave)
        os.set_blocking(self.master, False)
        self.path = os.ttyname(slave)
        self._slave: int | None = slave
        if not hold_slave:
            os.close(slave)
            self._slave = None
        self._pending = bytearray()
        self._max_pending = max_pending
        self.overflow_drops = 0  # whole records dropped because nobody read the port
        self.dropped_bytes = 0  # unwritten bytes dropped: nobody had the port open, or its reader took nothing
        self._lock = threading.Lock()
        self._written = 0  # bytes the line took, ever
        self._wake = threading.Event()
        self._closed = False
        self._writer = threading.Thread(target=self._drain, name="emu-pty-writer", daemon=True)
        self._writer.start()

    def _drain(self) -> None:
        """Push the backlog whenever the line takes more (a UART's transmit side)."""
        while not self._closed:
            self._wake.wait()  # set by a write that left a backlog, and by close: an idle port sleeps
            self._wake.clear()
            while not self._closed and self._pending:
                try:
                    select.select([], [self.master], [], 0.05)
                except (OSError, ValueError):
                    return
                self.flush()

    def read(self, timeout_s: float) -> bytes:
        r, _, _ = select.select([self.master], [], [], timeout_s)
        if not r:
            return b""
        try:
            return os.read(self.master, 65536)
        except OSError as err:
            if err.errno in (errno.EAGAIN, errno.EIO):
                return b""
            raise

    def write(self, data: bytes, *, droppable: bool = False) -> bool:
        """Queue ``data`` and push what the line takes now.  A droppable record (a stream frame) is
        discarded whole when the backlog is full, as a device's transmit FIFO would."""
        with self._lock:
            if droppable and len(self._pending) + len(data) > self._max_pending:
                self.overflow_drops += 1
                return False
            self._pending += data
            self._flush()
        if self._pending:
            self._wake.set()
        return True

    def _flush(self) -> None:
        while self._pending:
            try:
                n = os.write(self.master, self._pending[:65536])
            except OSError as err:
                if err.errno in (errno.EAGAIN, errno.EIO):
                    return
                raise
            del self._pending[:n]
            self._written += n

    def flush(self) -> None:
        with self._lock:
            self._flush()

    def discard_output(self) -> None:
        with self._lock:
            self._pending.clear()

    def has_reader(self) -> bool:
        """Whether a driver has the port open: always True for a port that holds its own slave.
        A pseudo-terminal whose slave nobody has open reports a hang-up on its master (readable,
        and reading it fails with EIO); bytes a driver wrote on it are read and ignored."""
        if self._slave is not None:
            return True
        try:
            readable, _, _ = select.select([self.master], [], [], 0)
            return not readable or bool(os.read(self.master, 4096))
        except BlockingIOError:
            return True
        except (OSError, ValueError):  # EIO: hung up (or the port is closed)
            return False

    def wait_sent(self, idle_s: float) -> bool:
        """Return once every byte written so far is on the line (the pseudo-terminal took it):
        pushed from the caller's thread too, as the driver's reader takes what came before, so a
        writer thread short of CPU holds nothing back.  What a port nobody has open holds, or what
        its reader left untaken for ``idle_s``, is dropped instead (counted in ``dropped_bytes``):
        the line lost it.  True if nothing was dropped."""
        seen, quiet_since = -1, time.monotonic()
        while True:
            with self._lock:
                self._flush()
                if not self._pending:
                    return True
                now = time.monotonic()
                if self._written != seen:  # the line took more (from here or the writer thread)
                    seen, quiet_since = self._written, now
                if now - quiet_since > idle_s or not self.has_reader():
                    self.dropped_bytes += len(self._pending)
                    self._pending.clear()
                    return False
            try:
                select.select([], [self.master], [], min(0.05, idle_s))
            except (OSError, ValueError):  # closed meanwhile
                return False

    def close(self) -> None:
        self._closed = True
        self._wake.set()
        self._writer.join(timeout=1.0)
        for fd in (self.master, self._slave):
            if fd is None:
                continue
            try:
                os.close(fd)
            except OSError:
                pass


class TcpServer:
    """A listening socket on 127.0.0.1 (port 0: ephemeral) with one thread per connection.

    ``pause()`` pulls the cable: connections drop and the port refuses new ones (the listener is
    closed, so a client sees ECONNREFUSED); ``resume()`` listens on the same port again."""

    def __init__(self, handler: Callable[[socket.socket], None], name: str, port: int = 0) -> None:
        self.name = name
        self._handler = handler
        self._sock: socket.socket | None = None
        self._conns: set[socket.socket] = set()
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._listen(port)
        self.port = self._sock.getsockname()[1]
        self.address = f"127.0.0.1:{self.port}"
        self._thread = threading.Thread(target=self._accept, name=f"emu-{name}-accept", daemon=True)
        self._thread.start()

    def _listen(self, port: int) -> None:
        sock = socket.create_server(("127.0.0.1", port))  # SO_REUSEADDR: the same port after a pause
        sock.settimeout(0.5)  # pause() and close() wake accept() by shutting the socket down; this is a backstop
        self._sock = sock

    def _accept(self) -> None:
        while not self._stop.is_set():
            sock = self._sock
            if sock is None:
                self._stop.wait(0.05)
                continue
            try:
                conn, _ = sock.accept()
            except (socket.timeout, OSError):
                continue
            conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            with self._lock:
                self._conns.add(conn)
            threading.Thread(target=self._serve, args=(conn,), name=f"emu-{self.name}-conn", daemon=True).start()

    def _serve(self, conn: socket.socket) -> None:
        try:
            self._handler(conn)
        except OSError:
            pass
        finally:
            with self._lock:
                self._conns.discard(conn)
            conn.close()

    @property
    def stopped(self) -> bool:
        return self._stop.is_set()

    def connections(self) -> list[socket.socket]:
        with self._lock:
            return list(self._conns)

    def drop_connections(self) -> None:
        for c in self.connections():
            try:
                c.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass
            c.close()
            with self._lock:
                self._conns.discard(c)

    def pause(self) -> None:
        sock, self._sock = self._sock, None
        if sock is not None:
            try:
                sock.shutdown(socket.SHUT_RDWR)  # stop listening now, even while accept() still holds it
            except OSError:
                pass
            sock.close()
        self.drop_connections()

    def resume(self) -> None:
        if self._sock is None and not self._stop.is_set():
            self._listen(self.port)

    def close(self) -> None:
        self._stop.set()
        self.pause()
        self._thread.join(timeout=1.0)


#: Fewer whole frames than this in a block: per frame is as quick (TCP and serial send two a block).
_BATCH_MIN_FRAMES = 8
#: Frames up to this size get their CRCs from one compiled pass (zlib per frame is quicker above it).
_SHORT_FRAME_BYTES = 256


@functools.lru_cache(maxsize=64)
def _frame_dtype(channels: int, samples: int) -> np.dtype:
    """One frame of :mod:`~hystbench.drivers.protocols.framing` as a packed record (header, samples, CRC)."""
    return np.dtype([("magic", "u1"), ("version", "u1"), ("stream_id", "u1"), ("channels", "u1"),
                     ("samples", "<u2"), ("flags", "<u2"), ("seq", "<u4"), ("first_index", "<i8"),
                     ("data", "<f4", (channels, samples)), ("crc", "<u4")])


def encode_frames(stream_id: int, seq0: int, first_index: int, data: np.ndarray, samples_per_frame: int,
                  flags: int = 0) -> list[bytes]:
    """The frames of a (C, n) block as bytes, the same bytes as :func:`frames_from_block` then
    :func:`encode_frame` per frame, built as one numpy record array (short frames, many a second,
    cost more in per-frame Python than in their bytes)."""
    data = np.asarray(data, dtype=np.float32)
    spf = int(samples_per_frame)
    if (data.ndim != 2 or not 1 <= data.shape[0] <= 255 or not 1 <= spf <= 0xFFFF
            or OVERHEAD + 4 * data.shape[0] * spf > MAX_FRAME_SIZE  # the per-frame path says what is wrong
            or data.shape[1] < _BATCH_MIN_FRAMES * spf):
        return [encode_frame(f) for f in frames_from_block(stream_id, seq0, first_index, data, spf, flags)]
    c, n = data.shape
    full = n // spf
    out: list[bytes] = []
    if full:
        rec = np.empty(full, dtype=_frame_dtype(c, spf))
        rec["magic"], rec["version"], rec["stream_id"], rec["channels"] = MAGIC, VERSION, stream_id & 0xFF, c
        rec["samples"], rec["flags"] = spf, flags & 0xFFFF
        k = np.arange(full, dtype=np.int64)
        rec["seq"] = (seq0 + k) % (1 << 32)
        rec["first_index"] = first_index + k * spf
        rec["data"] = data[:, :full * spf].reshape(c, full, spf).transpose(1, 0, 2)
        size = rec.dtype.itemsize
        if size <= _SHORT_FRAME_BYTES:  # short frames: one compiled pass over them all
            rec["crc"] = crc32_rows(rec.view(np.uint8).reshape(full, size), size - 4)
        else:
            flat, crc = memoryview(rec.view(np.uint8).reshape(-1)), zlib.crc32
            rec["crc"] = [crc(flat[o:o + size - 4]) for o in range(0, full * size, size)]
        buf = rec.tobytes()
        out = [buf[o:o + size] for o in range(0, full * size, size)]
    if n > full * spf:  # the block's last, shorter frame
        out.append(encode_frame(frames_from_block(stream_id, seq0 + full, first_index + full * spf,
                                                  data[:, full * spf:], spf, flags)[0]))
    return out


class FrameEmitter:
    """Cuts sample blocks into frames with running sequence numbers, applying stream faults.

    Frames are the framing codec's (:func:`encode_frames`) unless ``encode`` gives another one
    (``encode(seq0, first_index, data, flags) -> frames``, sequence numbers wrapping at
    ``seq_modulus``): the CAN FD integrator's ``can_stream``."""

    def __init__(self, stream_id: int, samples_per_frame: int, faults: Faults, *,
                 encode: Callable[[int, int, np.ndarray, int], list[bytes]] | None = None,
                 seq_modulus: int = 1 << 32) -> None:
        self.stream_id, self.samples_per_frame, self.faults = stream_id, samples_per_frame, faults
        self._encode = encode or (lambda seq0, first, data, flags: encode_frames(
            stream_id, seq0, first, data, samples_per_frame, flags))
        self.seq_modulus = seq_modulus
        self.seq = 0
        self.sent = self.dropped = self.corrupted = 0

    def skip(self, samples: int) -> None:
        """Count the frames of ``samples`` samples not sent (the stream is off), as an instrument's
        sequence counter runs on with its ADC."""
        self.seq = (self.seq + -(-samples // self.samples_per_frame)) % self.seq_modulus

    def emit(self, first_index: int, data: np.ndarray, flags: int = 0) -> list[bytes]:
        raws = self._encode(self.seq, first_index, data, flags)
        self.seq = (self.seq + len(raws)) % self.seq_modulus
        if not self.faults.stream_armed(first_index):
            self.sent += len(raws)
            return raws
        out = []  # a fault is armed: each frame is looked at, so it hits exactly the frame it is set for
        for k, raw in enumerate(raws):
            start = first_index + k * self.samples_per_frame
            if self.faults.is_silent(start) or self.faults.take("drop_frames", start):
                self.dropped += 1
                continue
            if self.faults.take("corrupt_frames", start):
                b = bytearray(raw)
                b[len(b) // 2] ^= 0x10  # a payload bit: the CRC no longer matches
                raw = bytes(b)
                self.corrupted += 1
            out.append(raw)
            self.sent += 1
        return out


class TcpStreamServer:
    """A stream port: every connected client gets length-prefixed frames; a client too slow to take
    them within ``send_timeout_s`` is dropped (it will see the exact gap after reconnecting)."""

    def __init__(self, name: str, emitter: FrameEmitter, send_timeout_s: float = 0.5) -> None:
        self.emitter = emitter
        self.send_timeout_s = send_timeout_s
        self.server = TcpServer(self._hold, name)
        self.address = self.server.address

    def _hold(self, conn: socket.socket) -> None:
        conn.settimeout(self.send_timeout_s)
        while not self.server.stopped:  # keep the connection until the client leaves
            r, _, _ = select.select([conn], [], [], 0.2)
            if r:
                try:
                    if not conn.recv(4096):
                        return
                except OSError:
                    return

    def send(self, first_index: int, data: np.ndarray, flags: int = 0) -> None:
        garbage = self.emitter.faults.take_bytes("stream_garbage", first_index)
        records = [length_prefixed(f) for f in self.emitter.emit(first_index, data, flags)]
        payload = garbage + b"".join(records)
        if not payload:
            return
        for conn in self.server.connections():
            try:
                conn.sendall(payload)
            except OSError:
                try:
                    conn.shutdown(socket.SHUT_RDWR)
                except OSError:
                    pass

    def close(self) -> None:
        self.server.close()


class PtyStreamSink:
    """A serial stream port: COBS records on a pseudo-terminal.

    What is sent while no driver has the port open is lost, as on a real port (the frames are
    still made, so sequence numbers and faults armed at an index run on with the sample clock).
    :meth:`wait_sent` is how the emulated bench keeps what waits in this port's backlog, unseen by a
    reader, to the newest tick (the module docstring); a reader that takes nothing for
    ``send_timeout_s`` meanwhile loses the backlog, as a TCP client that slow loses its connection."""

    def __init__(self, emitter: FrameEmitter, send_timeout_s: float = 0.5) -> None:
        self.emitter = emitter
        self.send_timeout_s = send_timeout_s
        self.port = PtyPort(hold_slave=False)
        self.path = self.port.path

    def send(self, first_index: int, data: np.ndarray, flags: int = 0) -> None:
        garbage = self.emitter.faults.take_bytes("stream_garbage", first_index)
        records = [b"\x00" + cobs_record(raw)  # a leading 0x00 lets a reader that joins now sync at once
                   for raw in self.emitter.emit(first_index, data, flags)]
        if not self.port.has_reader():
            self.port.discard_output()
            return
        if garbage:
            self.port.write(garbage, droppable=True)
        for record in records:
            self.port.write(record, droppable=True)

    def wait_sent(self) -> bool:
        """Return once everything sent is on the line (see :meth:`PtyPort.wait_sent`)."""
        return self.port.wait_sent(self.send_timeout_s)

    def close(self) -> None:
        self.port.close()


def scpi_messages(conn: socket.socket, stopped: Callable[[], bool]) -> Iterator[bytes]:
    """The SCPI program messages a client sends on ``conn``, until it closes or ``stopped()``
    (looked at every 0.2 s): the one receive loop of the SCPI emulators on TCP."""
    reader = ScpiMessageReader()
    conn.settimeout(0.2)
    while not stopped():
        try:
            data = conn.recv(65536)
        except socket.timeout:
            continue
        if not data:
            return
        yield from reader.feed(data)


#: An SCPI instrument's error queue holds this many entries; the last becomes -350 (queue overflow)
SCPI_QUEUE_MAX = 20


def queue_scpi_error(errors: "collections.deque[tuple[int, str]]", code: int, text: str | None = None) -> None:
    """Append ``code`` (with SCPI's standard text unless ``text``) to an instrument's error queue, as
    IEEE 488.2 says a full one does: its last entry becomes -350.  The caller holds the queue's lock."""
    if len(errors) >= SCPI_QUEUE_MAX:
        errors[-1] = (-350, SCPI_ERRORS[-350])
    else:
        errors.append((code, SCPI_ERRORS.get(code, "Error") if text is None else text))
