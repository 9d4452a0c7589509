"""What goes into a hystbench MCAP log: topics and their JSON schemas.

Every message is JSON (message encoding ``json``) with a ``jsonschema`` schema, which Foxglove and
the reference readers decode without plug-ins.  A raw sample block is the JSON framing of the one
raw-block codec (:mod:`hystbench.formats.raw_block`: samples as base64, exactly the bytes the
pipeline held); an estimate is :class:`hystbench.messages.Estimate`, its schema derived from the
class's fields.  The small messages' bytes are :func:`hystbench.messages.json_bytes` (zenoh sends
the same bytes).
"""

from __future__ import annotations

import json

from ...messages import Estimate
from ..raw_block import DTYPES

__all__ = ["RAW", "ESTIMATE", "COMPENSATOR", "STATUS", "STATS", "TOPICS", "SCHEMAS", "schema_bytes"]

RAW, ESTIMATE, COMPENSATOR, STATUS, STATS = "/raw", "/estimate", "/compensator", "/status", "/stats"

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
        "meta": {"type": "object", "additionalProperties": {"type": "number"},
                 "description": "the operating point: frequency_hz, current_pp_a, offset_a, output_on (1/0), "
                                "settling (1 when set), table"},
        "channels": {
            "type": "array",
            "items": {
                "type": "object",
                "properties": {
                    "name": {"type": "string"},
                    "unit": {"type": "string"},
                    "dtype": {"type": "string", "enum": list(DTYPES)},
                    "data": {"type": "string", "contentEncoding": "base64",
                             "description": "n little-endian values of dtype"},
                },
                "required": ["name", "unit", "dtype", "data"],
            },
        },
    },
    "required": ["first_index", "n", "fs_hz", "t0_ns", "flags", "gap_samples", "channels"],
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
    ESTIMATE: (Estimate.SCHEMA_TITLE, Estimate.json_schema()),
    COMPENSATOR: ("hystbench.CompensatorState", {"title": "hystbench.CompensatorState", **_OBJECT_SCHEMA}),
    STATUS: ("hystbench.Status", _STATUS_SCHEMA),
    STATS: ("hystbench.PipelineStats", {"title": "hystbench.PipelineStats", **_OBJECT_SCHEMA}),
}
TOPICS = tuple(SCHEMAS)


def schema_bytes(topic: str) -> bytes:
    """The JSON schema registered for ``topic``."""
    return json.dumps(SCHEMAS[topic][1]).encode()
