"""Binary framing of sample streams: one frame codec, two byte-stream wrappings.

A frame carries a run of samples of one instrument on the bench's common sample clock::

    offset  size  field (little-endian)
    0       1     magic 0xB5
    1       1     version (1)
    2       1     stream id
    3       1     channels C
    4       2     samples N per channel
    6       2     flags (hystbench.blocks.BlockFlags bits, e.g. CLIP = 4)
    8       4     sequence number (u32, wraps)
    12      8     first sample index (i64, common sample clock)
    20      4*C*N samples, float32, channel-major
    20+4CN  4     CRC-32 (zlib/IEEE 802.3) of every byte before it

Over serial each frame is COBS-encoded and ends with 0x00; over TCP each frame is preceded by its
length (u32).  (CAN FD's 64-byte data field has a denser frame of its own, ``can_stream``: this
header and float32 samples would leave room for 10.)  The first-sample index, not the
sequence number, is what makes gaps exact: a receiver knows how many samples it did not get no
matter how many frames were lost, merged by corruption or cut short.
"""

from __future__ import annotations

import functools
import struct
import zlib
from dataclasses import dataclass
from typing import Callable

import numpy as np

from ... import jit
from ...errors import ProtocolError

__all__ = [
    "MAGIC", "VERSION", "HEADER_SIZE", "OVERHEAD", "MAX_FRAME_SIZE", "FrameError", "Frame", "FrameBatch",
    "encode_frame", "decode_frame", "crc32_rows", "warm_crc_rows",
    "frames_from_block", "cobs_encode", "cobs_decode", "cobs_encode_reference",
    "cobs_decode_reference", "CobsDeframer", "LengthPrefixDeframer", "DeframerStats", "length_prefixed",
    "cobs_record",
]

MAGIC = 0xB5
VERSION = 1
_HEADER = struct.Struct("<BBBBHHIq")
HEADER_SIZE = _HEADER.size  # 20
_CRC = struct.Struct("<I")
_LEN = struct.Struct("<I")
OVERHEAD = HEADER_SIZE + _CRC.size  # bytes of a frame that are not samples
MAX_FRAME_SIZE = 65536  # a receiver never waits for a frame longer than this
_SEQ_MOD = 1 << 32


class FrameError(ProtocolError, ValueError):
    """Bytes that are not a valid frame (bad magic, version, length or CRC)."""


@dataclass(frozen=True, eq=False)
class Frame:
    """``samples[c, k]`` is channel c at sample index ``first_index + k``."""

    stream_id: int
    seq: int
    first_index: int
    samples: np.ndarray  # (C, N) float32
    flags: int = 0

    @property
    def n(self) -> int:
        return int(self.samples.shape[1])

    @property
    def end_index(self) -> int:
        return self.first_index + self.n


def encode_frame(frame: Frame) -> bytes:
    """One frame as bytes (header, little-endian float32 samples, CRC-32): what the
    instruments' streams send, so a damaged frame is detected, not read."""
    data = np.ascontiguousarray(frame.samples, dtype="<f4")
    if data.ndim != 2 or not 1 <= data.shape[0] <= 255 or data.shape[1] > 0xFFFF:
        raise ValueError(f"samples must be (channels 1..255, samples <= 65535), got {data.shape}")
    body = _HEADER.pack(MAGIC, VERSION, frame.stream_id & 0xFF, data.shape[0], data.shape[1],
                        frame.flags & 0xFFFF, frame.seq % _SEQ_MOD, frame.first_index) + data.tobytes()
    if len(body) + _CRC.size > MAX_FRAME_SIZE:
        raise ValueError(f"frame of {len(body) + 4} bytes exceeds {MAX_FRAME_SIZE}")
    return body + _CRC.pack(zlib.crc32(body))


def _check_header(buf: bytes | memoryview, offset: int = 0) -> int:
    """Total frame size announced by a header at ``offset``; FrameError if the header is impossible."""
    if len(buf) - offset < HEADER_SIZE:
        raise FrameError(f"frame too short: {len(buf) - offset} bytes")
    magic, version, _sid, c, n, _flags, _seq, _first = _HEADER.unpack_from(buf, offset)
    if magic != MAGIC:
        raise FrameError(f"bad magic 0x{magic:02x}")
    if version != VERSION:
        raise FrameError(f"unknown frame version {version}")
    size = OVERHEAD + 4 * c * n
    if c == 0 or size > MAX_FRAME_SIZE:
        raise FrameError(f"impossible frame shape {c} x {n}")
    return size


def decode_frame(buf: bytes | memoryview) -> Frame:
    """The frame in ``buf`` (exactly one frame, nothing else)."""
    size = _check_header(buf)
    if len(buf) != size:
        raise FrameError(f"frame length {len(buf)} != {size} announced by its header")
    body = bytes(buf[:-4])
    (crc,) = _CRC.unpack_from(buf, size - 4)
    if zlib.crc32(body) != crc:
        raise FrameError("CRC mismatch")
    _m, _v, sid, c, n, flags, seq, first = _HEADER.unpack_from(body)
    samples = np.frombuffer(body, dtype="<f4", offset=HEADER_SIZE).reshape(c, n)
    return Frame(sid, seq, first, samples, flags)


@dataclass(frozen=True, eq=False)
class FrameBatch:
    """Frames of one shape decoded together, in arrival order: frame i is ``samples[i]`` (C, N)
    from ``first_index[i]``.  What a CAN FD receiver hands on from one drain of the bus
    (``can_stream``): with 17 samples a message, a :class:`Frame` object and a Python pass per
    message would cost more than the samples themselves."""

    stream_id: np.ndarray  # (k,) int64
    seq: np.ndarray  # (k,) int64
    first_index: np.ndarray  # (k,) int64
    flags: np.ndarray  # (k,) int64
    samples: np.ndarray  # (k, C, N) float32

    def __len__(self) -> int:
        return int(self.seq.size)

    def take(self, rows: np.ndarray) -> "FrameBatch":
        """The frames at ``rows`` (a boolean mask or indices), in order."""
        return FrameBatch(self.stream_id[rows], self.seq[rows], self.first_index[rows], self.flags[rows],
                          self.samples[rows])

    def frames(self) -> list[Frame]:
        """One :class:`Frame` per row: the per-frame view every batch result must equal."""
        return [Frame(int(s), int(q), int(f), x, int(g)) for s, q, f, g, x in
                zip(self.stream_id, self.seq, self.first_index, self.flags, self.samples)]


def _crc32_table() -> np.ndarray:
    """zlib's CRC-32 (IEEE 802.3, reflected) one byte at a time: the table the kernels look up."""
    table = np.zeros(256, dtype=np.uint32)
    for i in range(256):
        c = i
        for _ in range(8):
            c = (c >> 1) ^ 0xEDB88320 if c & 1 else c >> 1
        table[i] = c
    return table


@functools.cache
def _crc_rows_kernel() -> Callable | None:
    """:func:`crc32_rows` compiled (None when numba is off)."""
    if not jit.enabled():
        return None
    table = _crc32_table()

    @jit.njit(cache=True, nogil=True)
    def crc_rows(rows: np.ndarray, length: int, table: np.ndarray) -> np.ndarray:
        out = np.empty(rows.shape[0], dtype=np.uint32)
        for r in range(rows.shape[0]):
            crc = np.uint32(0xFFFFFFFF)
            for j in range(length):
                crc = table[(crc ^ rows[r, j]) & 0xFF] ^ (crc >> np.uint32(8))
            out[r] = crc ^ np.uint32(0xFFFFFFFF)
        return out

    return lambda rows, length: crc_rows(rows, length, table)


def crc32_rows(rows: np.ndarray, length: int) -> np.ndarray:
    """``zlib.crc32`` of the first ``length`` bytes of each row of a (k, size) uint8 array, in one
    compiled pass when numba runs.  For short records (a CAN FD frame: 64 bytes, 5 900 a second)
    a zlib call and its slice per record cost more than the CRC; for long ones zlib is quicker."""
    kernel = _crc_rows_kernel()
    if kernel is None:
        return np.fromiter((zlib.crc32(row[:length]) for row in rows), dtype=np.uint32, count=len(rows))
    return kernel(np.ascontiguousarray(rows, dtype=np.uint8), int(length))


def frames_from_block(stream_id: int, seq0: int, first_index: int, data: np.ndarray,
                      samples_per_frame: int, flags: int = 0) -> list[Frame]:
    """Cut a (C, n) block into frames with consecutive sequence numbers (a loop per frame)."""
    data = np.asarray(data, dtype=np.float32)
    starts = range(0, data.shape[1], samples_per_frame)
    return [Frame(stream_id, (seq0 + i) % _SEQ_MOD, first_index + s, data[:, s:s + samples_per_frame], flags)
            for i, s in enumerate(starts)]


# --- COBS (consistent overhead byte stuffing): the serial wrapping -----------------------------
def cobs_encode_reference(data: bytes) -> bytes:
    """COBS encoding of ``data`` in plain Python: the reference the compiled codec must equal byte
    for byte, and the codec when numba is off."""
    out = bytearray()
    for part in bytes(data).split(b"\x00"):  # each part ends where a zero was (or at the end)
        while len(part) >= 254:
            out.append(0xFF)
            out += part[:254]
            part = part[254:]
        out.append(len(part) + 1)
        out += part
    return bytes(out)


def cobs_decode_reference(data: bytes) -> bytes:
    """Inverse of :func:`cobs_encode_reference` in plain Python (the reference, and the codec when
    numba is off); FrameError for input no encoder could have produced."""
    out = bytearray()
    i, n = 0, len(data)
    while i < n:
        code = data[i]
        if code == 0:
            raise FrameError("zero byte inside a COBS record")
        end = i + code
        if end > n:
            raise FrameError("COBS record truncated")
        chunk = data[i + 1:end]
        if 0 in chunk:
            raise FrameError("zero byte inside a COBS record")
        out += chunk
        i = end
        if code != 0xFF and i < n:
            out.append(0)
    return bytes(out)


_COBS_ERRORS = {-1: "zero byte inside a COBS record", -2: "COBS record truncated"}


@functools.cache
def _cobs_kernels() -> tuple[Callable, Callable] | None:
    """The compiled (encode, decode) pair, or None when numba is off.  Built on the first call, so
    importing the drivers never imports numba; a loop per byte in Python was 90 % of the serial
    stream's receive cost (issue 14)."""
    if not jit.enabled():
        return None

    @jit.njit(cache=True, nogil=True)
    def encode(src: np.ndarray, dst: np.ndarray) -> int:  # the reference's loop, byte by byte
        o, start, n = 0, 0, src.size
        while True:
            j = start
            while j < n and src[j] != 0:
                j += 1
            p = start
            while j - p >= 254:
                dst[o] = 0xFF
                dst[o + 1:o + 255] = src[p:p + 254]
                o += 255
                p += 254
            dst[o] = j - p + 1
            dst[o + 1:o + 1 + j - p] = src[p:j]
            o += 1 + j - p
            if j >= n:
                return o
            start = j + 1

    @jit.njit(cache=True, nogil=True)
    def decode(src: np.ndarray, dst: np.ndarray) -> int:  # decoded length, or -1/-2: _COBS_ERRORS
        i, o, n = 0, 0, src.size
        while i < n:
            code = src[i]
            if code == 0:
                return -1
            end = i + code
            if end > n:
                return -2
            for j in range(i + 1, end):
                b = src[j]
                if b == 0:
                    return -1
                dst[o] = b
                o += 1
            i = end
            if code != 0xFF and i < n:
                dst[o] = 0
                o += 1
        return o

    return encode, decode


def cobs_encode(data: bytes) -> bytes:
    """COBS encoding of ``data``: never contains 0x00, at most 1 + len/254 bytes longer (the same
    bytes as :func:`cobs_encode_reference`, compiled when numba runs)."""
    kernels = _cobs_kernels()
    if kernels is None:
        return cobs_encode_reference(data)
    src = np.frombuffer(data, dtype=np.uint8)
    dst = np.empty(src.size + src.size // 254 + 2, dtype=np.uint8)
    return dst[:kernels[0](src, dst)].tobytes()


def cobs_decode(data: bytes) -> bytes:
    """Inverse of :func:`cobs_encode`; FrameError for input no encoder could have produced (the
    same bytes and errors as :func:`cobs_decode_reference`, compiled when numba runs)."""
    kernels = _cobs_kernels()
    if kernels is None:
        return cobs_decode_reference(data)
    src = np.frombuffer(data, dtype=np.uint8)
    dst = np.empty(src.size, dtype=np.uint8)
    n = kernels[1](src, dst)
    if n < 0:
        raise FrameError(_COBS_ERRORS[n])
    return dst[:n].tobytes()


def warm_cobs() -> None:
    """Compile (or load from numba's cache) the COBS kernels now, not on a reader thread's first
    record: that costs 0.7 s (cached) to 3.4 s (cold), a backlog before the stream's first sample."""
    cobs_decode(cobs_encode(b"\x01\x00\x02"))


def warm_crc_rows() -> None:
    """:func:`warm_cobs` for :func:`crc32_rows` (the CAN FD stream frames' checks, both ends)."""
    crc32_rows(np.zeros((1, 1), dtype=np.uint8), 1)


def cobs_record(frame_bytes: bytes) -> bytes:
    """A frame as sent over serial: COBS bytes then the 0x00 delimiter."""
    return cobs_encode(frame_bytes) + b"\x00"


def length_prefixed(frame_bytes: bytes) -> bytes:
    """A frame as sent over TCP: u32 length then the frame."""
    return _LEN.pack(len(frame_bytes)) + frame_bytes


# --- receivers: bytes in, frames out, damage counted -------------------------------------------
@dataclass
class DeframerStats:
    """What a receiver had to throw away, counted, so damage on a link is visible, not silent."""

    frames: int = 0  #: valid frames delivered
    corrupt: int = 0  #: records that failed to decode (bad CRC, bad COBS, bad header)
    discarded_bytes: int = 0  #: bytes thrown away while looking for the next frame
    resyncs: int = 0  #: times the receiver lost and found the frame boundary again
    foreign: int = 0  #: valid frames of another stream id or shape, ignored


@dataclass
class _Expect:
    stream_id: int | None = None
    channels: int | None = None

    def accepts(self, frame: Frame) -> bool:
        return ((self.stream_id is None or frame.stream_id == self.stream_id)
                and (self.channels is None or frame.samples.shape[0] == self.channels))


class CobsDeframer:
    """Serial receiver: a record ends at each 0x00, so one bad record never costs the next one."""

    def __init__(self, stream_id: int | None = None, channels: int | None = None,
                 max_record: int = 2 * MAX_FRAME_SIZE) -> None:
        self._buf = bytearray()
        self._expect = _Expect(stream_id, channels)
        self._max = max_record
        self._synced = True
        self.stats = DeframerStats()

    def resync(self) -> None:
        """Joining a line mid-stream: bytes up to the first delimiter belong to no whole record."""
        self._buf.clear()
        self._synced = False

    def feed(self, data: bytes) -> list[Frame]:
        self._buf += data
        out: list[Frame] = []
        if not self._synced:
            end = self._buf.find(0)
            if end < 0:
                self.stats.discarded_bytes += len(self._buf)
                self._buf.clear()
                return out
            self.stats.discarded_bytes += end
            del self._buf[:end + 1]
            self._synced = True
        while True:
            end = self._buf.find(0)
            if end < 0:
                if len(self._buf) > self._max:  # no delimiter for too long: noise, drop it
                    self.stats.discarded_bytes += len(self._buf)
                    self.stats.resyncs += 1
                    self._buf.clear()
                return out
            record = bytes(self._buf[:end])
            del self._buf[:end + 1]
            if not record:
                continue  # idle delimiter (a sender may start with one to flush the line)
            try:
                frame = decode_frame(cobs_decode(record))
            except FrameError:
                self.stats.corrupt += 1
                self.stats.discarded_bytes += len(record) + 1
                continue
            if not self._expect.accepts(frame):
                self.stats.foreign += 1
                continue
            self.stats.frames += 1
            out.append(frame)

    def flush(self) -> list[Frame]:
        """At the end of input: what is left cannot be a whole record."""
        if self._buf:
            self.stats.discarded_bytes += len(self._buf)
            self.stats.corrupt += 1
            self._buf.clear()
        return []


class LengthPrefixDeframer:
    """TCP receiver.  In sync, each record is read by its length; after damage it scans for the next
    header that is consistent (magic, version, length, expected stream) and whose CRC checks."""

    _PAIR = bytes((MAGIC, VERSION))

    def __init__(self, stream_id: int | None = None, channels: int | None = None) -> None:
        self._buf = bytearray()
        self._expect = _Expect(stream_id, channels)
        self._in_sync = True
        self.stats = DeframerStats()

    def _candidate(self, final: bool) -> tuple[str, int]:
        """('frame', size) | ('wait', 0) | ('bad', 0) for a record starting at buffer offset 0."""
        buf = self._buf
        if len(buf) < _LEN.size + HEADER_SIZE:
            return ("bad", 0) if final else ("wait", 0)
        (length,) = _LEN.unpack_from(buf, 0)
        try:
            size = _check_header(buf, _LEN.size)
        except FrameError:
            return "bad", 0
        if size != length:
            return "bad", 0
        _m, _v, sid, c, _n, *_ = _HEADER.unpack_from(buf, _LEN.size)
        if (self._expect.stream_id is not None and sid != self._expect.stream_id) or (
                self._expect.channels is not None and c != self._expect.channels):
            return "bad", 0
        if len(buf) < _LEN.size + size:
            return ("bad", 0) if final else ("wait", 0)
        return "frame", size

    def _drop(self, n: int) -> None:
        del self._buf[:n]
        self.stats.discarded_bytes += n

    def _skip_to_next_header(self) -> None:
        """Drop bytes up to the next place a header could start (after at least one byte)."""
        if self._in_sync:  # the record at a trusted boundary is damaged (or garbage came between)
            self._in_sync = False
            self.stats.resyncs += 1
            self.stats.corrupt += 1
        pos = self._buf.find(self._PAIR, _LEN.size + 1)
        if pos < 0:  # keep a tail that may hold a prefix and the first header byte of the next frame
            self._drop(max(1, len(self._buf) - (_LEN.size + 1)))
        else:
            self._drop(pos - _LEN.size)

    def _run(self, final: bool) -> list[Frame]:
        out: list[Frame] = []
        while self._buf:
            kind, size = self._candidate(final)
            if kind == "wait":
                break
            if kind == "bad":
                if final and len(self._buf) < _LEN.size + HEADER_SIZE:
                    self._drop(len(self._buf))
                    break
                self._skip_to_next_header()
                continue
            record = bytes(self._buf[_LEN.size:_LEN.size + size])
            try:
                frame = decode_frame(record)
            except FrameError:
                # Even at a trusted boundary the length may be the damaged field: scan on rather
                # than skip the announced length, so no intact frame behind it is lost.
                self._skip_to_next_header()
                continue
            del self._buf[:_LEN.size + size]
            self._in_sync = True
            self.stats.frames += 1
            out.append(frame)
        return out

    def feed(self, data: bytes) -> list[Frame]:
        self._buf += data
        return self._run(final=False)

    def flush(self) -> list[Frame]:
        """At the end of input: decide every pending candidate with the bytes there are."""
        return self._run(final=True)
