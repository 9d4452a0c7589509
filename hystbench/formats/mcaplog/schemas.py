"""What goes into a hystbench MCAP log: topics, their JSON schemas, and the raw-block codec.

Every message is JSON (message encoding ``json``) with a ``jsonschema`` schema, which Foxglove and
the reference readers decode without plug-ins.  A raw sample block carries its samples as one
base64 string per channel (schema ``contentEncoding: base64``): little-endian ``float32`` or
``float64`` values, exactly the bytes the pipeline held.  Why not a binary message encoding:
Foxglove would show nothing of it; base64 costs 33 % before compression and about 1 ms per
megabyte, and zstd takes most of the 33 % back (the alphabet has 6 bits per character).
"""

from __future__ import annotations

import base64
import json
from typing import Any, Mapping

import numpy as np

from ...blocks import CHANNEL_UNITS, BlockFlags, SampleBlock
from ...errors import RecordingError

__all__ = ["RAW", "ESTIMATE", "COMPENSATOR", "STATUS", "STATS", "TOPICS", "SCHEMAS",
           "encode_block", "decode_block"]

RAW, ESTIMATE, COMPENSATOR, STATUS, STATS = "/raw", "/estimate", "/compensator", "/status", "/stats"


_DTYPES = {"float32": np.dtype("<f4"), "float64": np.dtype("<f8")}

_RAW_SCHEMA = {
    "title": "hystbench.RawBlock",
    "description": "Consecutive samples of every channel; time = first_index / fs_hz from the session start",
    "type": "object",
    "properties": {
        "first_index": {"type": "integer", "description": "sample index of the first sample"},
        "n": {"type": "integer", "description": "samples per channel"},
        "fs_hz": {"type": "number"},
        "t0_ns": {"type": "integer", "description": "first_index in ns from sample 0"},
        "flags": {"type": "integer", "description": "1 GAP, 2 OVERRUN, 4 CLIP"},
        "flag_names": {"type": "array", "items": {"type": "string"}},
        "gap_samples": {"type": "integer", "description": "sample indices missing just before this block"},
        "meta": {"type": "object", "additionalProperties": {"type": "number"}},
        "channels": {
            "type": "array",
            "items": {
                "type": "object",
                "properties": {
                    "name": {"type": "string"},
                    "unit": {"type": "string"},
                    "dtype": {"type": "string", "enum": list(_DTYPES)},
                    "data": {"type": "string", "contentEncoding": "base64",
                             "description": "n little-endian values of dtype"},
                },
                "required": ["name", "unit", "dtype", "data"],
            },
        },
    },
    "required": ["first_index", "n", "fs_hz", "t0_ns", "flags", "gap_samples", "channels"],
}

_NUM_MAP = {"type": "object", "additionalProperties": {"type": "number"}}
_ESTIMATE_SCHEMA = {
    "title": "hystbench.Estimate",
    "description": "Delays over one window of whole periods (positive: the later-named signal lags)",
    "type": "object",
    "properties": {
        "first_index": {"type": "integer"}, "end_index": {"type": "integer"}, "t_ns": {"type": "integer"},
        "frequency_Hz": {"type": "number"}, "frequency_std_Hz": {"type": "number"},
        "nominal_frequency_Hz": {"type": "number"}, "current_pp_A": {"type": "number"},
        "harmonic": {"type": "integer"}, "table": {"type": "integer"},
        "delays_s": _NUM_MAP, "delays_std_s": _NUM_MAP, "phases_deg": _NUM_MAP, "phases_std_deg": _NUM_MAP,
        "error": {"type": ["string", "null"]},
    },
    "required": ["first_index", "end_index", "t_ns"],
}
_OBJECT_SCHEMA = {"type": "object", "additionalProperties": True}
_STATUS_SCHEMA = {
    "title": "hystbench.Status",
    "type": "object",
    "properties": {"t_ns": {"type": "integer"}, "level": {"type": "string", "enum": ["info", "warning", "error"]},
                   "event": {"type": "string"}, "message": {"type": "string"}},
    "required": ["t_ns", "level", "event"],
    "additionalProperties": True,
}

#: topic -> (schema name, JSON schema)
SCHEMAS: dict[str, tuple[str, dict]] = {
    RAW: ("hystbench.RawBlock", _RAW_SCHEMA),
    ESTIMATE: ("hystbench.Estimate", _ESTIMATE_SCHEMA),
    COMPENSATOR: ("hystbench.CompensatorState", {"title": "hystbench.CompensatorState", **_OBJECT_SCHEMA}),
    STATUS: ("hystbench.Status", _STATUS_SCHEMA),
    STATS: ("hystbench.PipelineStats", {"title": "hystbench.PipelineStats", **_OBJECT_SCHEMA}),
}
TOPICS = tuple(SCHEMAS)


def _dtype_name(x: np.ndarray) -> str:
    if x.dtype == np.float32:
        return "float32"
    return "float64"


def encode_block(block: SampleBlock, units: Mapping[str, str] | None = None) -> bytes:
    """One raw block as the JSON of ``hystbench.RawBlock`` (built as bytes: the big base64 strings
    are not scanned again by a JSON encoder)."""
    units = units or {}
    head = {"first_index": int(block.first_index), "n": int(block.n), "fs_hz": float(block.fs_hz),
            "t0_ns": int(block.t0_ns), "flags": int(block.flags),
            "flag_names": [f.name for f in BlockFlags if f and f in block.flags],
            "gap_samples": int(block.gap_samples), "meta": {k: float(v) for k, v in block.meta.items()}}
    parts = [json.dumps(head, allow_nan=False)[:-1].encode(), b',"channels":[']
    for i, (name, x) in enumerate(block.channels.items()):
        dt = _dtype_name(np.asarray(x))
        arr = np.ascontiguousarray(x, dtype=_DTYPES[dt])
        unit = units.get(name) or CHANNEL_UNITS.get(name) or name.rsplit("_", 1)[-1]
        desc = json.dumps({"name": name, "unit": unit, "dtype": dt})[:-1].encode()
        parts += [b"," if i else b"", desc, b',"data":"', base64.b64encode(arr.data), b'"}']
    parts.append(b"]}")
    return b"".join(parts)


def decode_block(data: bytes | bytearray | memoryview, where: str = "raw block") -> SampleBlock:
    """The inverse of :func:`encode_block`; a malformed message is a RecordingError naming ``where``."""
    try:
        obj = json.loads(data)
        channels = {}
        for ch in obj["channels"]:
            dt = _DTYPES[ch["dtype"]]
            x = np.frombuffer(base64.b64decode(ch["data"], validate=True), dtype=dt)
            channels[ch["name"]] = x.astype(dt.newbyteorder("="), copy=False)
        n = int(obj["n"])
        if any(x.size != n for x in channels.values()):
            raise ValueError(f"channel lengths {[x.size for x in channels.values()]} differ from n={n}")
        return SampleBlock(int(obj["first_index"]), float(obj["fs_hz"]), channels,
                           flags=BlockFlags(int(obj["flags"])), gap_samples=int(obj["gap_samples"]),
                           meta=dict(obj.get("meta") or {}))
    except (ValueError, KeyError, TypeError) as err:
        raise RecordingError(f"{where}: not a hystbench.RawBlock: {err}") from err


def schema_bytes(topic: str) -> bytes:
    return json.dumps(SCHEMAS[topic][1]).encode()


def json_bytes(obj: Any) -> bytes:
    """Small messages: JSON without NaN (not JSON); NaN and inf become null."""
    return json.dumps(_finite(obj), separators=(",", ":"), allow_nan=False).encode()


def _finite(obj: Any) -> Any:
    if isinstance(obj, float):
        return obj if np.isfinite(obj) else None
    if isinstance(obj, dict):
        return {str(k): _finite(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_finite(v) for v in obj]
    if isinstance(obj, np.generic):
        return _finite(obj.item())
    return obj
