"""The flux integrator's CAN FD stream frame: 17 samples of 24 bits in one 64-byte data field.

The other instruments' streams carry the framing codec (``framing``: float32 samples behind a
20-byte header and a CRC-32), which on CAN FD leaves room for 10 samples a frame: 10 000 frames a
second at 100 kS/s, more than a CAN FD bus carries (a 64-byte frame with an 11-bit identifier
takes about 116 us at 1 Mbit/s arbitration and 8 Mbit/s data: some 8 600 frames a second at full
load).  An integrator's ADC gives 24-bit codes, so this frame sends those, 17 to a frame (5 900
frames a second, about 68 % of such a bus)::

    offset  size  field (little-endian)
    0       1     samples N in this frame (1..17; a block's last frame may be short)
    1       1     flags (hystbench.blocks.BlockFlags bits 0-7, e.g. CLIP = 4)
    2       2     sequence number (u16, wraps)
    4       6     first sample index (u48, common sample clock: 89 years at 100 kS/s)
    10      51    17 samples, int24 two's complement, LSB = FULL_SCALE_V / 2**23; unused slots 0
    61      3     the low 24 bits of the CRC-32 (zlib) of bytes 0-60

The bus's own CRC already refuses damaged frames; the check here is kept so that a frame damaged
before the controller (or by an emulated fault) is refused, never read: every error of one or two
bits in the 61 checked bytes is detected (tests/drivers/test_can_stream.py proves it).  A receiver
gets :class:`~.framing.Frame` s and :class:`~.framing.FrameBatch` es like every other stream.
"""

from __future__ import annotations

import zlib
from typing import Sequence

import numpy as np

from .can_integrator import FULL_SCALE_V
from .framing import Frame, FrameBatch, FrameError, crc32_rows

__all__ = ["FRAME_BYTES", "SAMPLES_PER_FRAME", "LSB_V", "SEQ_MODULUS", "CHECKED_BYTES", "encode_frames",
           "decode_frame", "decode_frames", "codes_of", "check_of"]

FRAME_BYTES = 64
SAMPLES_PER_FRAME = 17
_SAMPLES_AT = 10
CHECKED_BYTES = _SAMPLES_AT + 3 * SAMPLES_PER_FRAME  # 61: the check covers every byte before it
LSB_V = FULL_SCALE_V / 2 ** 23
SEQ_MODULUS = 1 << 16
_CODE_MAX = 2 ** 23 - 1
_INDEX_MAX = 1 << 48


def codes_of(volts: np.ndarray) -> np.ndarray:
    """The 24-bit ADC codes of ``volts`` (rounded to the nearest LSB, clipped to the code range: the
    integrator's output is clipped at full scale before it, with OVERLOAD set)."""
    return np.clip(np.rint(np.asarray(volts, dtype=np.float64) / LSB_V), -_CODE_MAX, _CODE_MAX).astype(np.int32)


def check_of(rows: np.ndarray) -> np.ndarray:
    """The check of each row of a (k, 64) uint8 array: the low 24 bits of zlib's CRC-32 of its
    first 61 bytes (one compiled pass, :func:`~.framing.crc32_rows`)."""
    return crc32_rows(rows, CHECKED_BYTES) & np.uint32(0xFFFFFF)


def encode_frames(seq0: int, first_index: int, volts: np.ndarray, flags: int = 0) -> list[bytes]:
    """The frames of a run of output voltages (any shape, read in order: an emulator's (1, n)
    block) from ``first_index``: 17 samples each, the last one shorter if the run is, sequence
    numbers from ``seq0``; built as one (k, 64) array."""
    codes = codes_of(np.asarray(volts).reshape(-1))
    n = codes.size
    if n == 0:
        return []
    if not (0 <= first_index and first_index + n <= _INDEX_MAX):
        raise ValueError(f"first sample index {first_index} does not fit the frame's 48 bits")
    k = -(-n // SAMPLES_PER_FRAME)
    padded = np.zeros(k * SAMPLES_PER_FRAME, dtype="<i4")
    padded[:n] = codes
    rows = np.zeros((k, FRAME_BYTES), dtype=np.uint8)
    rows[:, 0] = SAMPLES_PER_FRAME
    rows[-1, 0] = n - (k - 1) * SAMPLES_PER_FRAME
    rows[:, 1] = flags & 0xFF
    index = np.arange(k, dtype=np.int64)
    rows[:, 2:4] = ((seq0 + index) % SEQ_MODULUS).astype("<u2").view(np.uint8).reshape(k, 2)
    rows[:, 4:10] = (first_index + index * SAMPLES_PER_FRAME).astype("<u8").view(np.uint8).reshape(k, 8)[:, :6]
    rows[:, _SAMPLES_AT:CHECKED_BYTES] = padded.view(np.uint8).reshape(k, SAMPLES_PER_FRAME, 4)[:, :, :3].reshape(k, -1)
    rows[:, CHECKED_BYTES:] = check_of(rows).astype("<u4").view(np.uint8).reshape(k, 4)[:, :3]
    buf = rows.tobytes()
    return [buf[o:o + FRAME_BYTES] for o in range(0, k * FRAME_BYTES, FRAME_BYTES)]


def _volts(rows: np.ndarray) -> np.ndarray:
    """(k, 17) float32 volts of the sample slots of (k, 64) rows: int24 codes sign-extended (the
    three bytes shifted into the top of an int32, then shifted back down) times the LSB."""
    k = rows.shape[0]
    wide = np.zeros((k, SAMPLES_PER_FRAME, 4), dtype=np.uint8)
    wide[:, :, 1:] = rows[:, _SAMPLES_AT:CHECKED_BYTES].reshape(k, SAMPLES_PER_FRAME, 3)
    codes = wide.view("<i4")[:, :, 0] >> 8
    return (codes * LSB_V).astype(np.float32)


def _fields(rows: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(samples N, flags, sequence, first index) of each of (k, 64) rows, as int64."""
    k = rows.shape[0]
    wide = np.zeros((k, 8), dtype=np.uint8)
    wide[:, :6] = rows[:, 4:10]
    seq = np.ascontiguousarray(rows[:, 2:4]).view("<u2")[:, 0]
    return (rows[:, 0].astype(np.int64), rows[:, 1].astype(np.int64), seq.astype(np.int64),
            wide.view("<u8")[:, 0].astype(np.int64))


def _valid(rows: np.ndarray) -> np.ndarray:
    """Rows whose check matches and whose sample count is possible."""
    sent = rows[:, CHECKED_BYTES:].astype(np.uint32) << np.array([0, 8, 16], dtype=np.uint32)
    return (check_of(rows) == sent.sum(axis=1, dtype=np.uint32)) & (rows[:, 0] >= 1) & (rows[:, 0] <= SAMPLES_PER_FRAME)


def decode_frame(data: bytes | bytearray, stream_id: int) -> Frame:
    """One data field as a :class:`Frame` of ``stream_id`` (one channel, N samples); FrameError if
    it is not a valid frame.  The reference :func:`decode_frames` equals."""
    if len(data) != FRAME_BYTES:
        raise FrameError(f"CAN FD stream frame of {len(data)} bytes, expected {FRAME_BYTES}")
    raw = bytes(data)
    if zlib.crc32(raw[:CHECKED_BYTES]) & 0xFFFFFF != int.from_bytes(raw[CHECKED_BYTES:], "little"):
        raise FrameError("CRC mismatch")
    n = raw[0]
    if not 1 <= n <= SAMPLES_PER_FRAME:
        raise FrameError(f"impossible sample count {n}")
    codes = [int.from_bytes(raw[_SAMPLES_AT + 3 * j:_SAMPLES_AT + 3 * j + 3], "little", signed=True) for j in range(n)]
    samples = (np.array(codes, dtype=np.int64) * LSB_V).astype(np.float32).reshape(1, n)
    return Frame(stream_id, int.from_bytes(raw[2:4], "little"), int.from_bytes(raw[4:10], "little"), samples, raw[1])


def decode_frames(payloads: Sequence[bytes | bytearray], stream_id: int) -> tuple[list[Frame | FrameBatch], int]:
    """Data fields in arrival order to what a stream accepts, and how many were refused: full
    frames in runs as :class:`FrameBatch` es (decoded together), short ones as :class:`Frame` s,
    in their order.  Fields of another length are refused."""
    whole = [p for p in payloads if len(p) == FRAME_BYTES]
    if not whole:
        return [], len(payloads)
    rows = np.frombuffer(b"".join(whole), dtype=np.uint8).reshape(len(whole), FRAME_BYTES)
    valid = _valid(rows)
    refused = len(payloads) - int(np.count_nonzero(valid))
    if refused:
        rows = rows[valid]
    n, flags, seq, first = _fields(rows)
    full = n == SAMPLES_PER_FRAME
    volts = _volts(rows)
    out: list[Frame | FrameBatch] = []
    cuts = np.flatnonzero(~full).tolist()  # short frames: their own Frame, between runs of full ones
    for lo, short in zip([0, *[c + 1 for c in cuts]], [*cuts, len(n)]):
        if short > lo:
            run = slice(lo, short)
            out.append(FrameBatch(np.full(short - lo, stream_id, dtype=np.int64), seq[run], first[run], flags[run],
                                  volts[run, None, :]))
        if short < len(n):
            m = int(n[short])
            out.append(Frame(stream_id, int(seq[short]), int(first[short]), volts[short, None, :m].copy(),
                             int(flags[short])))
    return out, refused
