"""One MCAP chunk decoded in bounded memory, for the reader and for ``recover``.

Why not mcap's own ``breakup_chunk``: it calls ``zstandard.decompress(data, uncompressed_size)``,
and zstandard allocates and fills whatever size the compressed frame declares, whatever the chunk
says: a 6 kB chunk can demand 200 MB, or gigabytes.  Here a chunk's declared size is capped
(:data:`MAX_RECORD_BYTES`), decompression stops one byte past it, and the bytes must then match
the declared size and (for ``recover``, when the writer stored one: hystbench's does) the CRC.
The records inside are then split by mcap's own code, from bytes already checked.  A chunk that
cannot be decoded is a :class:`RecordingError` saying why (without the file: the caller names it).
"""

from __future__ import annotations

import struct
import zlib
from typing import Any

from ...errors import RecordingError

__all__ = ["MAGIC", "MAX_RECORD_BYTES", "CHUNK_FIXED_BYTES", "parse_chunk", "chunk_records"]

#: The 8 bytes every MCAP file starts (and, when finished, ends) with.
MAGIC = b"\x89MCAP0\r\n"
#: The longest record, and the largest uncompressed chunk, read (256 MiB).  hystbench writes
#: 256 KiB chunks; a chunk holds at least one message, and a raw block of a few seconds at
#: 1 MS/s is tens of MB.  Anything longer is damage (or a decompression bomb), not a log.
MAX_RECORD_BYTES = 256 << 20
#: A chunk record's body besides its compression name and data: message start and end time,
#: uncompressed size (u64 each), uncompressed CRC, compression name length (u32 each), data length (u64).
CHUNK_FIXED_BYTES = 40
_COMPRESSIONS = ("", "zstd", "lz4")
_HEAD = struct.Struct("<QQQII")


def parse_chunk(body: bytes, *, exact: bool = False) -> Any:
    """The :class:`mcap.records.Chunk` whose record body is ``body``, its fields checked to fit:
    ``exact`` also asks that the data end where the record ends (as every writer does), which a
    candidate found by scanning damaged bytes must prove."""
    from mcap.records import Chunk

    if len(body) < CHUNK_FIXED_BYTES:
        raise RecordingError(f"chunk record of {len(body)} bytes, shorter than its header")
    start, end, size, crc, name_len = _HEAD.unpack_from(body, 0)
    if name_len > 4 or CHUNK_FIXED_BYTES + name_len > len(body):
        raise RecordingError(f"compression name of {name_len} bytes")
    try:
        compression = body[32:32 + name_len].decode("ascii")
    except UnicodeDecodeError:
        compression = "?"
    if compression not in _COMPRESSIONS:
        raise RecordingError(f"unknown compression {body[32:32 + name_len]!r}")
    (data_len,) = struct.unpack_from("<Q", body, 32 + name_len)
    data_end = CHUNK_FIXED_BYTES + name_len + data_len
    if data_end > len(body) or (exact and data_end != len(body)):
        raise RecordingError(f"chunk data of {data_len} bytes in a record of {len(body)}")
    if size > MAX_RECORD_BYTES:
        raise RecordingError(f"chunk of {size} bytes uncompressed, over MAX_RECORD_BYTES ({MAX_RECORD_BYTES})")
    return Chunk(compression=compression, data=body[CHUNK_FIXED_BYTES + name_len:data_end],
                 message_start_time=start, message_end_time=end, uncompressed_crc=crc, uncompressed_size=size)


def _decompress(chunk: Any) -> bytes:
    """The chunk's bytes, never more than its declared size plus one (so a longer frame is caught)."""
    limit = chunk.uncompressed_size + 1
    if chunk.compression == "":
        return chunk.data
    if chunk.compression == "zstd":
        try:
            import zstandard
        except ImportError as err:
            raise RecordingError("a zstd chunk needs the zstandard package (pip install zstandard)") from err
        parts, got = [], 0
        try:
            with zstandard.ZstdDecompressor().stream_reader(chunk.data) as reader:
                while got < limit and (part := reader.read(min(1 << 20, limit - got))):
                    parts.append(part)
                    got += len(part)
        except zstandard.ZstdError as err:
            raise RecordingError(f"zstd: {err}") from err
        return b"".join(parts)
    try:
        import lz4.frame
    except ImportError as err:
        raise RecordingError("an lz4 chunk needs the lz4 package (pip install lz4)") from err
    try:
        return lz4.frame.LZ4FrameDecompressor().decompress(chunk.data, max_length=limit)
    except RuntimeError as err:  # lz4.frame's error for a damaged frame
        raise RecordingError(f"lz4: {err}") from err


def chunk_records(chunk: Any, *, check_crc: bool = True) -> list:
    """The schema, channel and message records inside ``chunk`` (a :class:`mcap.records.Chunk`),
    after checking its size and (``check_crc``, when the writer stored one) its CRC; a
    :class:`RecordingError` says what is wrong."""
    from mcap.records import Chunk
    from mcap.stream_reader import breakup_chunk

    if chunk.uncompressed_size > MAX_RECORD_BYTES:
        raise RecordingError(f"chunk of {chunk.uncompressed_size} bytes uncompressed, over MAX_RECORD_BYTES")
    data = _decompress(chunk)
    if len(data) > chunk.uncompressed_size:  # decompression stopped there: the frame holds more
        raise RecordingError(f"chunk decompresses to more than {chunk.uncompressed_size} bytes, the size its header says")
    if len(data) < chunk.uncompressed_size:
        raise RecordingError(f"chunk decompresses to {len(data)} bytes, its header says {chunk.uncompressed_size}")
    if check_crc and chunk.uncompressed_crc and zlib.crc32(data) != chunk.uncompressed_crc:
        raise RecordingError(f"CRC mismatch (the chunk says {chunk.uncompressed_crc:#010x}, "
                         f"its bytes give {zlib.crc32(data):#010x})")
    plain = Chunk(compression="", data=data, message_start_time=chunk.message_start_time,
                  message_end_time=chunk.message_end_time, uncompressed_crc=0, uncompressed_size=len(data))
    try:
        return breakup_chunk(plain, validate_crc=False)
    except Exception as err:  # mcap raises several kinds on records it cannot split
        raise RecordingError(f"records inside the chunk: {type(err).__name__}: {err}") from err
