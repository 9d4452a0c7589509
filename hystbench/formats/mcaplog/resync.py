"""One MCAP record read and checked at a given offset, and the next valid record after damage.

Why a module of its own: ``recover`` walks a log record by record, and after a damaged region it
must find where whole records start again.  Every record is an opcode byte and a u64 length, so a
candidate is a byte with an anchor opcode followed by a length that fits in the file; a chunk's
header must also be self-consistent (its compression name and data length add up to the record
length).  Those tests run on a window of the file at a time with numpy, so the Python loop runs
per surviving candidate (a handful per damaged region), not per byte.  A survivor must then
prove itself: a chunk decompresses to its declared size with its CRC, a schema, channel or
metadata record parses to exactly its length with printable names.

Every record, in the walk as in the scan, must be exactly as long as its fields, and a record
other than a chunk (whose CRC proves it) must be followed by the start of another (a known
opcode, and a length that fits unless it is a chunk, which may be the one a killed writer cut):
a length that damage changed would otherwise be followed, and swallow the whole records after
it.  For the same reason private records (opcodes 0x80-0xff, which hystbench never writes) are
not trusted.  (MCAP lets later versions append fields; a record with more than this reader
knows is then skipped as a damaged region, and the next anchor resumes the walk.)
"""

from __future__ import annotations

import io
import struct
from dataclasses import dataclass
from typing import Any, BinaryIO

import numpy as np

from ...errors import RecordingError
from .chunks import CHUNK_FIXED_BYTES, MAX_RECORD_BYTES, chunk_records, parse_chunk

__all__ = ["Source", "Record", "Damage", "Resync", "read_record", "next_valid_record", "WINDOW_BYTES"]

#: Bytes scanned per numpy pass when looking for the next valid record.
WINDOW_BYTES = 1 << 20
_MARGIN = 64  # bytes read past a window: a candidate's opcode, length and chunk header (9 + 40 + 4 + 8)
_OPCODE_LENGTH = struct.Struct("<BQ")
# the smallest body of each anchor: schema id, name, encoding, data; channel id, schema id, topic,
# encoding, metadata; metadata name and map; a chunk's fixed fields
_CHUNK, _SCHEMA, _CHANNEL, _METADATA, _MESSAGE, _FOOTER = 0x06, 0x03, 0x04, 0x0C, 0x05, 0x02
_MIN_BODY = {_CHUNK: CHUNK_FIXED_BYTES, _SCHEMA: 14, _CHANNEL: 16, _METADATA: 8}
_IS_ANCHOR = np.zeros(256, dtype=bool)  # a lookup table by byte value: one pass over a window
_IS_ANCHOR[list(_MIN_BODY)] = True
_HIGH_BITS = MAX_RECORD_BYTES.bit_length()  # a record's length has no bit above this


class Source:
    """The damaged file, read at offsets (a record at a time: memory stays one record)."""

    def __init__(self, fh: BinaryIO, size: int) -> None:
        self.fh, self.size = fh, size

    def read(self, offset: int, n: int) -> bytes:
        self.fh.seek(offset)
        return self.fh.read(n)


@dataclass(frozen=True)
class Record:
    """A valid record: ``value`` is the parsed mcap record (a chunk: the list of records inside)."""

    offset: int
    opcode: int
    length: int
    value: Any

    @property
    def end(self) -> int:
        return self.offset + 9 + self.length


@dataclass(frozen=True)
class Damage:
    """No valid record at an offset (a result, not an exception: damage is what ``recover`` expects
    to meet); ``why`` says what is wrong, ``chunk`` is 1 when it was a chunk whose header was
    whole (so a chunk is known to be lost there)."""

    why: str
    chunk: int = 0


@dataclass(frozen=True)
class Resync:
    """Where the next valid record starts (the file's size if none), the record, and how many
    damaged chunks the scan recognised on the way."""

    offset: int
    record: Record | None
    damaged_chunks: int


def _classes() -> dict[int, Any]:
    from mcap import records as r
    from mcap.opcode import Opcode as O

    return {O.HEADER: r.Header, O.FOOTER: r.Footer, O.SCHEMA: r.Schema, O.CHANNEL: r.Channel,
            O.MESSAGE_INDEX: r.MessageIndex, O.CHUNK_INDEX: r.ChunkIndex, O.ATTACHMENT: r.Attachment,
            O.ATTACHMENT_INDEX: r.AttachmentIndex, O.STATISTICS: r.Statistics, O.METADATA: r.Metadata,
            O.METADATA_INDEX: r.MetadataIndex, O.SUMMARY_OFFSET: r.SummaryOffset, O.DATA_END: r.DataEnd}


def _parse(opcode: int, body: bytes, anchor: bool) -> Any:
    """The record's value, whose fields fill ``body``; an ``anchor`` also has printable names."""
    from mcap.data_stream import ReadDataStream
    from mcap.records import Message

    stream = ReadDataStream(io.BytesIO(body))
    if opcode == _MESSAGE:
        if len(body) < 22:
            raise ValueError(f"a message record of {len(body)} bytes, shorter than its header")
        return Message.read(stream, len(body))
    value = _classes()[opcode].read(stream)
    if stream.count != len(body):
        raise ValueError(f"its fields take {stream.count} of its {len(body)} bytes")
    if anchor:
        names = {_SCHEMA: lambda v: (v.name, v.encoding), _CHANNEL: lambda v: (v.topic, v.message_encoding),
                 _METADATA: lambda v: (v.name,)}.get(opcode, lambda v: ())(value)
        if not all(n and n.isprintable() for n in names):
            raise ValueError(f"empty or unprintable name in {names!r}")
    return value


def read_record(src: Source, pos: int, *, anchor: bool = False) -> Record | Damage:
    """The valid record at ``pos``, or :class:`Damage` saying why there is none; an ``anchor``
    (a record found by scanning damaged bytes) must also have printable names."""
    from mcap.opcode import Opcode

    head = src.read(pos, 9)
    if len(head) < 9:
        return Damage(f"the file ends inside a record header at offset {pos}")
    opcode, length = _OPCODE_LENGTH.unpack(head)
    if opcode not in Opcode._value2member_map_:
        return Damage(f"no record starts at offset {pos} (opcode 0x{opcode:02x})")
    name = Opcode(opcode).name.lower()
    if length > src.size - pos - 9:
        cut = opcode == _CHUNK and length <= MAX_RECORD_BYTES  # a chunk the writer did not finish
        return Damage(f"{name} of {length} bytes at offset {pos} runs past the end of the file", chunk=int(cut))
    if length > MAX_RECORD_BYTES:
        return Damage(f"{name} of {length} bytes at offset {pos} is over MAX_RECORD_BYTES ({MAX_RECORD_BYTES})")
    body = src.read(pos + 9, length)
    if opcode == _CHUNK:
        try:
            chunk = parse_chunk(body, exact=True)
        except RecordingError as err:
            return Damage(f"chunk at offset {pos}: {err}")
        try:
            return Record(pos, opcode, length, chunk_records(chunk))
        except RecordingError as err:
            return Damage(f"chunk at offset {pos}: {err}", chunk=1)
    try:
        record = Record(pos, opcode, length, _parse(opcode, body, anchor))
    except Exception as err:  # mcap's readers raise several kinds on bytes that are no record
        return Damage(f"{name} at offset {pos} does not parse ({type(err).__name__}: {err})")
    if opcode != _FOOTER and not _record_starts(src, record.end):
        return Damage(f"{name} at offset {pos} is followed by no record (its length, {length}, may be damaged)")
    return record


def _record_starts(src: Source, pos: int) -> bool:
    """Whether a record may start at ``pos``: the end of the file, or a known opcode with a length
    that fits (a chunk's may not: the writer may have been killed while writing it)."""
    from mcap.opcode import Opcode

    if pos == src.size:
        return True
    head = src.read(pos, 9)
    if len(head) < 9:
        return False
    opcode, length = _OPCODE_LENGTH.unpack(head)
    return opcode in Opcode._value2member_map_ and (opcode == _CHUNK or length <= src.size - pos - 9)


def _uint(buf: np.ndarray, at: np.ndarray, width: int) -> np.ndarray:
    """The little-endian unsigned integers of ``width`` bytes at each offset ``at`` of ``buf``."""
    return buf[at[:, None] + np.arange(width)].view(f"<u{width}").reshape(-1).astype(np.uint64)


def _candidates(buf: np.ndarray, n: int, room: int) -> np.ndarray:
    """Offsets in ``buf[:n]`` where a valid anchor record may start: an anchor opcode, a length
    that fits the ``room`` bytes left in the file from ``buf[0]`` and the caps, and for a chunk a
    header whose compression name and data length add up to the record's length.  ``buf`` holds
    at least ``n + _MARGIN`` bytes (zero-padded at the end of the file)."""
    at = np.flatnonzero(_IS_ANCHOR[buf[:n]])
    # the length's high bytes must be zero (lengths are under MAX_RECORD_BYTES): in damaged or
    # compressed bytes this leaves a few candidates in a million, before any wider gather
    top = 1 + _HIGH_BITS // 8  # the first byte of the length (after the opcode) that must be small
    high = np.bitwise_or.reduce(buf[at[:, None] + np.arange(top + 1, 9)], axis=1) if top < 8 else 0
    at = at[(high == 0) & (buf[at + top] >> (_HIGH_BITS % 8) == 0)]
    op = buf[at]
    length = _uint(buf, at + 1, 8)
    left = np.maximum(room - at.astype(np.int64) - 9, 0).astype(np.uint64)
    smallest = np.select([op == k for k in _MIN_BODY], list(_MIN_BODY.values())).astype(np.uint64)
    ok = (length <= left) & (length <= MAX_RECORD_BYTES) & (length >= smallest)
    name_len = _uint(buf, at + 9 + 28, 4)
    named = np.isin(name_len, (0, 3, 4))  # "", "lz4", "zstd"
    name_len = np.where(named, name_len, 0)
    data_len = _uint(buf, at + 9 + 32 + name_len.astype(np.int64), 8)
    size = _uint(buf, at + 9 + 16, 8)
    with np.errstate(over="ignore"):
        whole = named & (size <= MAX_RECORD_BYTES) & (length == CHUNK_FIXED_BYTES + name_len + data_len)
    return at[ok & ((op != _CHUNK) | whole)]


def next_valid_record(src: Source, start: int) -> Resync:
    """The first valid schema, channel, metadata or chunk record at or after ``start``."""
    damaged = 0
    for lo in range(start, src.size, WINDOW_BYTES):
        raw = src.read(lo, WINDOW_BYTES + _MARGIN)
        n = min(WINDOW_BYTES, len(raw))
        buf = np.frombuffer(raw.ljust(n + _MARGIN, b"\0"), dtype=np.uint8)
        for at in _candidates(buf, n, src.size - lo).tolist():
            record = read_record(src, lo + at, anchor=True)
            if isinstance(record, Damage):
                damaged += record.chunk
                continue
            return Resync(record.offset, record, damaged)
    return Resync(src.size, None, damaged)
