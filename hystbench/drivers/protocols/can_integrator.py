"""The flux integrator's CAN protocol: identifiers, command codes and payloads.

    host -> integrator  0x600 + node  classic CAN, 8 bytes: opcode, 0, 0, 0, value (u32 or f32 LE)
    integrator -> host  0x580 + node  8 bytes: opcode, result, 0, 0, value
    sample stream       0x180 + node  CAN FD, 64 bytes, bit-rate switch: one ``can_stream``
                                      frame (17 samples of the output voltage, 24 bits each)
    heartbeat           0x700 + node  every 100 ms, 2 bytes: 0x05 (operational), status bits

The integrator digitises its output U = gain * (integral of the sense-coil voltage) / turns, so
U / gain is the flux through one turn in Wb.  ``result`` is one of ``RESULTS``.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from types import MappingProxyType
from typing import Mapping

__all__ = ["Op", "OPS", "RESULTS", "STATUS", "FULL_SCALE_V", "DEVICE_TYPE", "command_id", "reply_id",
           "stream_id", "heartbeat_id", "encode_command", "decode_command", "encode_reply", "decode_reply",
           "HEARTBEAT_PERIOD_S"]

FULL_SCALE_V = 10.0
DEVICE_TYPE = 0x4649  # 'FI'
HEARTBEAT_PERIOD_S = 0.1


def command_id(node: int) -> int:
    """CAN id of requests to ``node`` (CANopen-style: 0x600 + node)."""
    return 0x600 + node


def reply_id(node: int) -> int:
    """CAN id of ``node``'s replies (0x580 + node)."""
    return 0x580 + node


def stream_id(node: int) -> int:
    """CAN id of ``node``'s sample stream (0x180 + node)."""
    return 0x180 + node


def heartbeat_id(node: int) -> int:
    """CAN id of ``node``'s heartbeat (0x700 + node)."""
    return 0x700 + node


@dataclass(frozen=True)
class Op:
    """One operation of the integrator's command table: driver and emulator read the same row."""

    code: int
    value: str  # 'none', 'u32', 'f32'
    reply: str  # type of the reply's value
    minimum: float | None = None
    maximum: float | None = None
    doc: str = ""


#: name -> operation.  The one table of the integrator's commands.
OPS: Mapping[str, Op] = MappingProxyType({
    "identify": Op(0x01, "none", "u32", doc="reply value: device type << 16 | firmware (major << 8 | minor)"),
    "reset": Op(0x02, "none", "none", doc="zero the integral (drift reset)"),
    "hold": Op(0x03, "u32", "none", 0, 1, doc="1: freeze the output, 0: integrate"),
    "set_gain": Op(0x04, "f32", "f32", 1.0, 1e9, doc="output volts per weber (after / turns)"),
    "get_gain": Op(0x05, "none", "f32"),
    "set_turns": Op(0x06, "u32", "u32", 1, 10_000, doc="sense-coil turns the integral is divided by"),
    "get_turns": Op(0x07, "none", "u32"),
    "get_status": Op(0x08, "none", "u32", doc="STATUS bits"),
    "stream": Op(0x09, "u32", "none", 0, 1, doc="1: send the sample stream"),
})
RESULTS: Mapping[int, str] = MappingProxyType({0: "OK", 1: "unknown command", 2: "value out of range",
                                               3: "not allowed now"})
STATUS: Mapping[str, int] = MappingProxyType({"INTEGRATING": 0x01, "HOLD": 0x02, "OVERLOAD": 0x04,
                                              "STREAMING": 0x08})

_MSG = struct.Struct("<BBxx4s")


def _pack_value(kind: str, value: float | int | None) -> bytes:
    if kind == "f32":
        return struct.pack("<f", float(value))
    if kind == "u32":
        return struct.pack("<I", int(value))
    return b"\x00" * 4


def _unpack_value(kind: str, raw: bytes) -> float | int | None:
    if kind == "f32":
        return struct.unpack("<f", raw)[0]
    if kind == "u32":
        return struct.unpack("<I", raw)[0]
    return None


def encode_command(name: str, value: float | int | None = None) -> bytes:
    """The 8-byte request for operation ``name`` (its value packed as the table says)."""
    op = OPS[name]
    return _MSG.pack(op.code, 0, _pack_value(op.value, value))


def decode_command(data: bytes) -> tuple[str | None, int, float | int | None]:
    """(operation name or None if unknown, opcode, value)."""
    if len(data) != _MSG.size:
        return None, data[0] if data else 0, None
    code, _, raw = _MSG.unpack(data)
    for name, op in OPS.items():
        if op.code == code:
            return name, code, _unpack_value(op.value, raw)
    return None, code, None


def encode_reply(code: int, result: int, kind: str = "none", value: float | int | None = None) -> bytes:
    """The 8-byte reply (opcode, result code, value): the emulator's side of :func:`decode_reply`."""
    return _MSG.pack(code, result, _pack_value(kind, value))


def decode_reply(data: bytes, name: str) -> tuple[int, int, float | int | None]:
    """(opcode, result, value) of a reply to operation ``name``; ValueError if not 8 bytes."""
    if len(data) != _MSG.size:
        raise ValueError(f"reply of {len(data)} bytes, expected {_MSG.size}")
    code, result, raw = _MSG.unpack(data)
    return code, result, _unpack_value(OPS[name].reply, raw) if result == 0 else None
