"""The raw-block codec: one header, one dtype table, two framings of the same block.

Every framing carries the whole block: ``first_index``, ``n``, ``fs_hz``, ``t0_ns``, ``flags`` (and
their names), ``gap_samples``, ``meta`` (the operating point: see
:meth:`hystbench.messages.OperatingPoint.to_meta`; numbers only) and per channel its ``name``,
``unit`` and ``dtype`` (little-endian ``float32`` or ``float64``: exactly the bytes the pipeline
held).

- **binary** (zenoh, ``application/octet-stream;hystbench.raw.v1``): ``u32`` little-endian header
  length ``H``, ``H`` bytes of UTF-8 JSON header (the fields above plus ``"v": 1``), then for each
  channel of ``header["channels"]`` in order, ``n`` values of its ``dtype``.  Decoding gives
  read-only views of the payload (no copy).
- **JSON** (MCAP, schema ``hystbench.RawBlock``): the same header as one JSON object whose channels
  also hold ``data``, the values as base64 (``contentEncoding: base64``), which Foxglove and the
  reference readers decode without plug-ins.  Why not binary in MCAP: Foxglove would show nothing
  of it; base64 costs 33 % before compression and about 1 ms per megabyte, and zstd takes most of
  the 33 % back (the alphabet has 6 bits per character).

:func:`decode` reads both: a binary payload has its header's ``{`` at byte 4, a JSON one opens
with ``{"first_index"`` (byte 4 is ``r``), as every log written by hystbench does.
"""

from __future__ import annotations

import base64
import json
import math
import struct
from typing import Any, Mapping

import numpy as np

from ..blocks import CHANNEL_UNITS, BlockFlags, SampleBlock
from ..errors import RecordingError

__all__ = ["DTYPES", "BINARY_ENCODING", "encode_binary", "encode_json", "decode"]

#: dtype name in the header -> the little-endian numpy dtype of the values.
DTYPES: Mapping[str, np.dtype] = {"float32": np.dtype("<f4"), "float64": np.dtype("<f8")}
#: The zenoh encoding of a binary payload.
BINARY_ENCODING = "application/octet-stream;hystbench.raw.v1"

_U32 = struct.Struct("<I")


def _head(block: SampleBlock) -> dict[str, Any]:
    """The block's header without its channels: the one place its fields are named."""
    return {"first_index": int(block.first_index), "n": int(block.n), "fs_hz": float(block.fs_hz),
            "t0_ns": int(block.t0_ns), "flags": int(block.flags),
            "flag_names": [f.name for f in BlockFlags if f and f in block.flags],
            "gap_samples": int(block.gap_samples), "meta": {k: float(v) for k, v in block.meta.items()}}


def _channel(block: SampleBlock, name: str, units: Mapping[str, str] | None) -> tuple[dict[str, str], np.ndarray]:
    """A channel's description and its values as contiguous little-endian float32 or float64."""
    x = np.asarray(block.channels[name])
    dt = "float32" if x.dtype == np.float32 else "float64"
    unit = (units or {}).get(name) or CHANNEL_UNITS.get(name) or name.rsplit("_", 1)[-1]
    return {"name": name, "unit": unit, "dtype": dt}, np.ascontiguousarray(x, dtype=DTYPES[dt])


def encode_binary(block: SampleBlock, channels: list[str] | None = None,
                  units: Mapping[str, str] | None = None) -> bytes:
    """The block (or only ``channels``) in the binary framing."""
    names = list(block.channels) if channels is None else channels
    descs, arrays = zip(*(_channel(block, c, units) for c in names)) if names else ((), ())
    head = json.dumps({"v": 1, **_head(block), "channels": list(descs)}, allow_nan=False).encode()
    return b"".join([_U32.pack(len(head)), head, *(a.data for a in arrays)])


def encode_json(block: SampleBlock, units: Mapping[str, str] | None = None) -> bytes:
    """The block in the JSON framing (built as bytes: the big base64 strings are not scanned again
    by a JSON encoder)."""
    parts = [json.dumps(_head(block), allow_nan=False)[:-1].encode(), b',"channels":[']
    for i, name in enumerate(block.channels):
        desc, arr = _channel(block, name, units)
        parts += [b"," if i else b"", json.dumps(desc)[:-1].encode(), b',"data":"', base64.b64encode(arr.data), b'"}']
    parts.append(b"]}")
    return b"".join(parts)


#: The fastest sample clock a block may state: beyond any digitiser, small enough that a count of
#: samples over seconds stays an integer (a block at 1e308 S/s overflowed a replay's).
MAX_FS_HZ = 1e12


def _block(head: Mapping[str, Any], channels: dict[str, np.ndarray]) -> SampleBlock:
    n = int(head["n"])
    if any(x.size != n for x in channels.values()):
        raise ValueError(f"channel lengths {[x.size for x in channels.values()]} differ from n={n}")
    if not channels:  # a writer never makes one; a reader takes its channels from the first block
        raise ValueError("no channels")
    fs = float(head["fs_hz"])  # JSON's NaN and Infinity parse: they are no sample clock
    if not (math.isfinite(fs) and 0 < fs <= MAX_FS_HZ):
        raise ValueError(f"fs_hz must be a sample rate in (0, {MAX_FS_HZ:g}] Hz, got {fs!r}")
    gap = int(head["gap_samples"])
    if n < 0 or gap < 0:
        raise ValueError(f"n and gap_samples must be >= 0, got {n} and {gap}")
    meta = head.get("meta") or {}
    if not isinstance(meta, dict):
        raise ValueError(f"meta must be an object, got {meta!r}")
    meta = {str(k): float(v) for k, v in meta.items()}
    bad = [k for k, v in meta.items() if not math.isfinite(v)]
    if bad:  # written with allow_nan=False: a NaN frequency there failed a replay ("cannot convert NaN")
        raise ValueError(f"meta {bad[0]} = {meta[bad[0]]!r}: a finite number is written there")
    return SampleBlock(int(head["first_index"]), fs, channels, flags=BlockFlags(int(head["flags"])), gap_samples=gap,
                       meta=meta)


def _decode_binary(buf: memoryview) -> SampleBlock:
    (h,) = _U32.unpack_from(buf, 0)
    head = json.loads(bytes(buf[4:4 + h]))
    off, n, channels = 4 + h, int(head["n"]), {}
    for ch in head["channels"]:
        dt = DTYPES[ch["dtype"]]
        channels[ch["name"]] = np.frombuffer(buf, dtype=dt, count=n, offset=off)
        off += n * dt.itemsize
    if off != len(buf):
        raise ValueError(f"payload has {len(buf)} bytes, the header describes {off}")
    return _block(head, channels)


def _decode_json(data: bytes | bytearray | memoryview) -> SampleBlock:
    obj = json.loads(bytes(data) if isinstance(data, memoryview) else data)
    channels = {}
    for ch in obj["channels"]:
        dt = DTYPES[ch["dtype"]]
        x = np.frombuffer(base64.b64decode(ch["data"], validate=True), dtype=dt)
        channels[ch["name"]] = x.astype(dt.newbyteorder("="), copy=False)
    return _block(obj, channels)


def decode(data: bytes | bytearray | memoryview, where: str = "raw block") -> SampleBlock:
    """A block from either framing; anything else is a :class:`RecordingError` naming ``where``."""
    buf = memoryview(data)
    try:
        if len(buf) > 4 and buf[4] == 0x7B:  # "{" after the u32 length: binary
            return _decode_binary(buf)
        return _decode_json(data)
    except (ValueError, KeyError, TypeError, OverflowError, struct.error, RecursionError) as err:  # JSONDecodeError: a
        # ValueError; RecursionError: JSON nested deeper than the parser's stack (damaged or hostile bytes)
        raise RecordingError(f"{where}: not a hystbench.RawBlock: {type(err).__name__}: {str(err)[:200]}") from err
