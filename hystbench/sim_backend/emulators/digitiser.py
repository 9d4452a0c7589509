"""Emulated digitiser: the rig's four signals sampled on the emulator's clock, served over SCPI on
127.0.0.1 in any dialect of ``drivers/protocols/scpi_digitiser.py`` (the table the driver reads).

Wiring: each signal reaches a channel as volts = SI value / the bench file's ``scales`` (the
analogue outputs of the current monitor, charge amplifier, integrator and generator), sampled as
16-bit codes over +-10 V (``y_increment`` = 10/32768 V, exact in binary).  Once ``RUN`` is
received every clock block is kept in the channel's memory (``memory_points`` deep: the oldest is
lost first, and a read then starts later: the gap the driver must report).  A preamble query
latches the source channel's next segment (at most ``points``) from where its last data read
stopped; the data query sends that segment as a definite-length block and moves on.  Errors go to
the queue read by ``SYST:ERR?`` (-113 unknown header, -224 illegal value, -109 missing value); in a
dialect that reads events (Tektronix) they set ``*ESR?``'s error bits and ``ALLEv?`` returns them
all as positive event codes (113, 224, 109).
"""

from __future__ import annotations

import collections
import socket
import threading
from typing import Any, Callable, Mapping

import numpy as np

from ...blocks import SampleBlock
from ...drivers.protocols import scpi
from ...drivers.protocols import scpi_digitiser as sd
from .common import Faults, TcpServer, queue_scpi_error, scpi_messages

__all__ = ["DigitiserEmulator", "RANGE_V", "Y_INCREMENT"]

RANGE_V = 10.0
Y_INCREMENT = RANGE_V / 32768  #: volts per code: 2**-15 x 10, exact


class DigitiserEmulator:
    """``wiring``: signal -> (channel number 1..4, SI units per volt)."""

    kind = "digitiser"

    def __init__(self, fs_hz: float, wiring: Mapping[str, tuple[int, float]], *, dialect: str = "generic",
                 memory_points: int = 4_000_000, identity: str = "HYSTBENCH,SIMDIG-4,0001,1.0",
                 segment_points: int = 25_000) -> None:
        self.fs_hz, self.dialect = float(fs_hz), sd.dialect(dialect)
        self.wiring = {s: (int(ch), float(scale)) for s, (ch, scale) in wiring.items()}
        self.memory_points, self.identity = int(memory_points), identity
        self.faults = Faults()
        self.running = False
        self.max_points = 100_000
        self.source = 1
        self.errors: collections.deque[tuple[int, str]] = collections.deque()
        self.esr = 0  # the event status register (``*ESR?`` reads and clears it)
        self.commands_seen: list[bytes] = []
        #: faults of the next data replies holding points, in order: "truncate" sends half the block and stops
        self.block_faults: collections.deque[str] = collections.deque()
        self.lost_points = 0  # memory overwritten before it was read, per channel, summed
        self._memory: dict[int, collections.deque[tuple[int, np.ndarray]]] = {
            ch: collections.deque() for ch, _ in self.wiring.values()}
        self._held = dict.fromkeys(self._memory, 0)
        self._read_at: dict[int, int | None] = dict.fromkeys(self._memory)
        self._latched: dict[int, tuple[int, np.ndarray]] = {}
        self._lock = threading.RLock()
        self.data_replies = threading.Semaphore(0)  # released once per data block sent (tests wait on it)
        # segmented acquisition: DIGitize arms ``segment_count`` segments of ``segment_points``, each
        # triggered by a rising zero crossing of command_V (the generator's period starts)
        self.segmented, self.segment_count, self.segment_points = False, 16, int(segment_points)
        self.segment_index = 1
        self._armed = False
        self._filling: tuple[int, dict[int, list[np.ndarray]], int] | None = None  # trigger, parts, points
        self._segments: list[tuple[int, dict[int, np.ndarray]]] = []  # (trigger index, channel -> codes)
        self._last_cmd = 0.0
        self._batch_done = threading.Event()
        self.triggers: list[list[int]] = []  #: each batch's trigger indices (the truth tests compare with)
        self.server = TcpServer(self._serve, "digitiser")

    @property
    def addresses(self) -> dict[str, str]:
        return {"visa": f"TCPIP::127.0.0.1::{self.server.port}::SOCKET", "scpi_tcp": self.server.address}

    # --- sampling ----------------------------------------------------------------------------------
    def on_block(self, block: SampleBlock) -> None:
        if self._armed:
            with self._lock:
                self._segment_block(block)
        if not self.running:
            return
        with self._lock:
            for signal, (ch, scale) in self.wiring.items():
                codes, _ = sd.volts_to_codes(np.asarray(block.channels[signal], dtype=np.float64) / scale, Y_INCREMENT)
                mem = self._memory[ch]
                mem.append((block.first_index, codes))
                self._held[ch] += codes.size
                if self._read_at[ch] is None:
                    self._read_at[ch] = block.first_index
                while self._held[ch] - mem[0][1].size >= self.memory_points:
                    first, old = mem.popleft()
                    self._held[ch] -= old.size
                    if self._read_at[ch] < first + old.size:
                        self.lost_points += first + old.size - self._read_at[ch]
                        self._read_at[ch] = first + old.size
                    self._latched.pop(ch, None)

    def _segment_block(self, block: SampleBlock) -> None:
        """Segmented acquisition: fill segments from their triggers until the batch is complete."""
        cmd = np.asarray(block.channels["command_V"], dtype=np.float64)
        codes = {ch: sd.volts_to_codes(np.asarray(block.channels[sig], dtype=np.float64) / scale, Y_INCREMENT)[0]
                 for sig, (ch, scale) in self.wiring.items()}
        prev = np.concatenate([[self._last_cmd], cmd[:-1]])
        self._last_cmd = float(cmd[-1]) if cmd.size else self._last_cmd
        pos, n = 0, cmd.size
        while self._armed and pos < n:
            if self._filling is None:
                hits = np.flatnonzero((prev[pos:] < 0) & (cmd[pos:] >= 0))
                if not hits.size:
                    return
                pos += int(hits[0])
                self._filling = (block.first_index + pos, {ch: [] for ch in codes}, 0)
            trig, parts, got = self._filling
            take = min(self.segment_points - got, n - pos)
            for ch, c in codes.items():
                parts[ch].append(c[pos:pos + take])
            pos, got = pos + take, got + take
            self._filling = (trig, parts, got)
            if got == self.segment_points:
                self._segments.append((trig, {ch: np.concatenate(p) for ch, p in parts.items()}))
                self._filling = None
                if len(self._segments) == self.segment_count:
                    self._armed = False
                    self.triggers.append([t for t, _ in self._segments])
                    self._batch_done.set()

    def _segment(self, ch: int) -> tuple[int, np.ndarray]:
        """The next unread points of channel ``ch`` (at most ``max_points``), contiguous: a hole in
        the memory (acquisition stopped, blocks lost) ends a segment, and the next one starts after
        it, so the driver sees the jump (a gap) and no sample is carried to another's index."""
        start = self._read_at[ch]
        if start is None:
            return 0, np.empty(0, sd.CODE_DTYPE)
        parts, n, at = [], 0, start
        for first, codes in self._memory[ch]:
            if first + codes.size <= at:
                continue
            if first > at:  # a hole
                if parts:
                    break
                start = at = first
            parts.append(codes[at - first:][:self.max_points - n])
            n += parts[-1].size
            at += parts[-1].size
            if n >= self.max_points:
                break
        return start, (np.concatenate(parts) if parts else np.empty(0, sd.CODE_DTYPE))

    # --- the instrument ----------------------------------------------------------------------------
    def push_error(self, code: int, text: str | None = None) -> None:
        with self._lock:
            queue_scpi_error(self.errors, code, text)
            self.esr |= {1: 0x20, 2: 0x10, 3: 0x08, 4: 0x04}.get(abs(code) // 100, 0)

    def _channel(self, arg: str) -> int | None:
        for k, name in enumerate(self.dialect.channel_names, start=1):
            if scpi.header_matches(name, arg) and k in self._memory:
                return k
        return None

    def _find(self, header: str, is_query: bool, arg: str) -> str | None:
        """The operation a message names; None (and an error queued) when none."""
        candidates = [op for op, c in self.dialect.commands.items() if c.query == is_query and c.matches(header)]
        for op in candidates:
            want = self.dialect.command(op).argument
            if is_query or want is None or op in ("source", "points", "segment_count", "segment_index") \
                    or scpi.header_matches(want, arg):
                return op
        self.push_error(-224 if candidates else -113)
        return None

    def handle(self, message: bytes) -> bytes | None:
        """Execute one program message; the reply (with terminator) or None."""
        wait = self.dialect.command("wait")
        header, is_query, raw = scpi.split_command(message)
        if is_query and wait is not None and wait.matches(header):  # *OPC?: 1 once the armed batch is complete
            self.commands_seen.append(message)
            for _ in range(300):  # at most 30 s, and no longer than the server lives
                if self._batch_done.wait(0.1):
                    return b"1\n"
                if self.server.stopped:
                    break
            return None  # no answer: the driver's bounded wait times out
        with self._lock:
            self.commands_seen.append(message)
            arg = raw.decode("ascii", "replace").strip()
            if not is_query and scpi.header_matches("HEADer", header) and self.dialect.on_open:
                return None  # the dialect's HEADer OFF: replies carry no headers (the only form emulated)
            op = self._find(header, is_query, arg)
            if op is None:
                return None
            if is_query:
                return self._query(op)
            if op == "source":
                ch = self._channel(arg)
                if ch is None:
                    self.push_error(-224 if arg else -109)
                else:
                    self.source = ch
            elif op == "points":
                try:
                    self.max_points = int(arg)
                    if self.max_points < 1:
                        raise ValueError(arg)
                except ValueError:
                    self.max_points = 100_000
                    self.push_error(-224)
            elif op in ("segment_count", "segment_index"):
                try:
                    value = int(arg)
                    if value < 1 or (op == "segment_index" and value > len(self._segments)):
                        raise ValueError(arg)
                    setattr(self, op, value)
                except ValueError:
                    self.push_error(-224)
            elif op == "acquire_mode":
                self.segmented, self.running = True, False
            elif op == "arm":
                if not self.segmented:
                    self.push_error(-221)  # settings conflict: armed outside segmented mode (not emulated)
                else:
                    self._segments, self._filling, self.segment_index = [], None, 1
                    self._batch_done.clear()
                    self._armed = True
            elif op == "run":
                self.running = True
            elif op == "stop":
                self.running = False
            elif op == "clear_status":
                self.errors.clear()
                self.esr = 0
            return None

    def _query(self, op: str) -> bytes:
        if op == "identity":
            return self.identity.encode() + b"\n"
        if op == "event_status":
            esr, self.esr = self.esr, 0
            return f"{esr}".encode() + b"\n"
        if op == "error" and self.dialect.reads_events:
            events = [(abs(c), t) for c, t in self.errors]
            self.errors.clear()
            return sd.format_event_reply(events).encode() + b"\n"
        if op == "error":
            return scpi.format_error_reply(*(self.errors.popleft() if self.errors else (0, None))).encode() + b"\n"
        if op == "sample_rate":
            return f"{self.fs_hz:.10g}".encode() + b"\n"
        ch = self.source
        if self.segmented and op in ("preamble", "data", "time_tag"):
            return self._segment_reply(op, ch)
        if op == "preamble":
            self._latched[ch] = seg = self._segment(ch)
            return self._preamble(*seg).format(self.dialect).encode() + b"\n"
        first, codes = self._latched.pop(ch, None) or self._segment(ch)
        if codes.size:
            self._read_at[ch] = first + codes.size
        return sd.encode_block(codes.astype(sd.CODE_DTYPE, copy=False).tobytes()) + b"\n"

    def _segment_reply(self, op: str, ch: int) -> bytes:
        """The selected segment (x_origin 0: its first point is its trigger), its tag, or its data."""
        if not self._segments:
            self.push_error(-230, "Data corrupt or stale")  # nothing acquired yet
            codes, trig = np.empty(0, sd.CODE_DTYPE), 0
        else:
            trig, by_ch = self._segments[self.segment_index - 1]
            codes = by_ch[ch]
        if op == "time_tag":
            return f"{(trig - self._segments[0][0]) / self.fs_hz if self._segments else 0.0:.12e}".encode() + b"\n"
        if op == "preamble":
            return sd.Preamble(int(codes.size), 1.0 / self.fs_hz, 0.0, 0.0, Y_INCREMENT, 0.0, 0.0) \
                .format(self.dialect).encode() + b"\n"
        return sd.encode_block(codes.astype(sd.CODE_DTYPE, copy=False).tobytes()) + b"\n"

    def _preamble(self, first: int, codes: np.ndarray) -> sd.Preamble:
        return sd.Preamble(int(codes.size), 1.0 / self.fs_hz, first / self.fs_hz, 0.0, Y_INCREMENT, 0.0, 0.0)

    # --- transport ---------------------------------------------------------------------------------
    def _reply(self, send: Callable[[bytes], Any], reply: bytes | None, is_data: bool) -> None:
        if reply is None or not self.faults.before_reply():
            return
        head = 2 + int(reply[1:2]) if is_data and reply[:1] == b"#" else 0  # '#', the digit, the length digits
        if is_data and self.block_faults and len(reply) - head - 1 > 0:  # a block with data in it
            fault = self.block_faults.popleft()
            if fault == "truncate":
                reply = reply[:head + (len(reply) - head - 1) // 2]
        send(reply)
        self.faults.sent_reply()
        if is_data:
            self.data_replies.release()

    def _serve(self, conn: socket.socket) -> None:
        data_cmd = self.dialect.command("data")
        for msg in scpi_messages(conn, lambda: self.server.stopped):
            if self.faults.is_silent():
                continue
            replies, is_data = [], False
            for unit in sd.split_units(msg):  # IEEE 488.2: the replies of one message joined by ';'
                header, is_query, _ = scpi.split_command(unit)
                is_data |= is_query and data_cmd.matches(header)
                if (r := self.handle(unit)) is not None:
                    replies.append(r[:-1])
            self._reply(conn.sendall, b";".join(replies) + b"\n" if replies else None, is_data)

    def disconnect(self) -> None:
        self.faults.silent = True
        self.server.pause()

    def reconnect(self) -> None:
        self.server.resume()
        self.faults.silent = False

    def close(self) -> None:
        self.server.close()
