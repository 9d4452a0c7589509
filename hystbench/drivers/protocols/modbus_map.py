"""The current amplifier's Modbus register map and the Modbus codecs an emulator needs.

Holding registers, addresses from 0 (40001 in the 1-based "4xxxx" notation).  Values are 16-bit
integers in the units below; the driver converts to SI.  The driver talks through pymodbus; this
module also holds the server-side PDU codec, MBAP header and RTU CRC used by the emulator.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from types import MappingProxyType
from typing import Callable, Mapping

from ...errors import InstrumentError

__all__ = ["Register", "REGISTERS", "CONTROL", "STATUS", "FAULTS", "MODEL_ID", "EXCEPTIONS", "WATCHDOG_MIN_MS",
           "ModbusException", "crc16", "rtu_request_length", "server_response", "mbap", "MBAP"]

MODEL_ID = 0x4841  #: register 0 of this amplifier model ('HA')


@dataclass(frozen=True)
class Register:
    """One register of the amplifier's map with its unit, scale and limits: driver and emulator
    read the same row."""

    address: int
    name: str
    access: str  # 'R' or 'RW'
    unit: str  # of the raw integer
    scale: float = 1.0  # SI value = raw * scale
    signed: bool = False
    minimum: int = 0
    maximum: int = 0xFFFF
    doc: str = ""

    def to_si(self, raw: int) -> float:
        if self.signed and raw >= 0x8000:
            raw -= 0x10000
        return raw * self.scale

    def to_raw(self, value: float) -> int:
        raw = int(round(value / self.scale))
        if not self.minimum <= raw <= self.maximum:
            raise ValueError(f"{self.name} = {value:g} is outside {self.minimum * self.scale:g}.."
                             f"{self.maximum * self.scale:g}")
        return raw & 0xFFFF


def _r(*args, **kw) -> Register:
    return Register(*args, **kw)


#: name -> register.  The one place the map is written; docs/protocols.md lists the same table.
REGISTERS: Mapping[str, Register] = MappingProxyType({r.name: r for r in [
    _r(0, "model_id", "R", "", doc=f"0x{MODEL_ID:04X} for this model"),
    _r(1, "firmware", "R", "", doc="major * 256 + minor"),
    _r(2, "control", "RW", "bits", maximum=0x0003, doc="CONTROL bits"),
    _r(3, "status", "R", "bits", doc="STATUS bits (live)"),
    _r(4, "faults", "R", "bits", doc="FAULTS bits (latched until CLEAR_FAULTS)"),
    _r(5, "gain", "RW", "mA/V", 1e-3, minimum=10, maximum=10_000, doc="transconductance"),
    _r(6, "current_limit", "RW", "mA", 1e-3, minimum=0, maximum=20_000, doc="trip level of |i|"),
    _r(7, "watchdog", "RW", "ms", 1e-3, minimum=0, maximum=60_000,
       doc="0 = off, else at least 50 ms; with no request for this long the output is disabled (WATCHDOG fault)"),
    _r(8, "current", "R", "mA", 1e-3, signed=True, minimum=-32768, maximum=32767, doc="output current now"),
    _r(9, "current_rms", "R", "mA", 1e-3, doc="rms over the newest monitor block"),
    _r(10, "temperature", "R", "0.01 degC", 0.01, signed=True, minimum=-32768, maximum=32767,
       doc="output stage"),
]})
N_REGISTERS = 11
#: The shortest watchdog the amplifier takes, in its register's unit (0 switches it off; 1-49 ms are
#: refused with exception 3, ILLEGAL DATA VALUE: docs/protocols.md).
WATCHDOG_MIN_MS = 50

CONTROL = MappingProxyType({"ENABLE": 0x0001, "CLEAR_FAULTS": 0x0002})
STATUS = MappingProxyType({"ENABLED": 0x0001, "FAULT": 0x0002, "WATCHDOG_ARMED": 0x0004})
FAULTS = MappingProxyType({"OVERCURRENT": 0x0001, "OVERTEMP": 0x0002, "WATCHDOG": 0x0004,
                           "INTERLOCK": 0x0008, "SUPPLY": 0x0010})

EXCEPTIONS = MappingProxyType({1: "ILLEGAL FUNCTION", 2: "ILLEGAL DATA ADDRESS", 3: "ILLEGAL DATA VALUE",
                               4: "SERVER DEVICE FAILURE", 6: "SERVER DEVICE BUSY"})


class ModbusException(InstrumentError):
    """Raised by a server's register callbacks: becomes an exception response with ``code``."""

    def __init__(self, code: int) -> None:
        super().__init__(EXCEPTIONS.get(code, str(code)))
        self.code = code


def crc16(data: bytes) -> int:
    """Modbus RTU CRC-16 (poly 0xA001 reflected, init 0xFFFF); sent low byte first."""
    crc = 0xFFFF
    for b in data:
        crc ^= b
        for _ in range(8):
            crc = (crc >> 1) ^ 0xA001 if crc & 1 else crc >> 1
    return crc


def rtu_request_length(buf: bytes) -> int | None:
    """Length of the RTU request at the start of ``buf`` (unit, fc, ..., crc), None if unknowable yet."""
    if len(buf) < 2:
        return None
    fc = buf[1]
    if fc in (3, 4, 6):
        return 8
    if fc == 16:
        return None if len(buf) < 7 else 9 + buf[6]
    return 4  # unknown function: unit + fc + crc, answered with ILLEGAL FUNCTION


MBAP = struct.Struct(">HHHB")  # transaction id, protocol id (0), length (unit + PDU), unit id


def mbap(tid: int, unit: int, pdu: bytes) -> bytes:
    """A Modbus TCP frame: the MBAP header in front of ``pdu``."""
    return MBAP.pack(tid, 0, len(pdu) + 1, unit) + pdu


def server_response(pdu: bytes, read: Callable[[int, int], list[int]],
                    write: Callable[[int, list[int]], None]) -> bytes:
    """The response PDU to a request PDU (functions 3, 6, 16; others: ILLEGAL FUNCTION)."""
    fc = pdu[0] if pdu else 0
    try:
        if fc == 3:
            if len(pdu) != 5:
                raise ModbusException(3)
            addr, count = struct.unpack(">HH", pdu[1:5])
            if not 1 <= count <= 125:
                raise ModbusException(3)
            values = read(addr, count)
            return struct.pack(">BB", 3, 2 * count) + struct.pack(f">{count}H", *values)
        if fc == 6:
            if len(pdu) != 5:
                raise ModbusException(3)
            addr, value = struct.unpack(">HH", pdu[1:5])
            write(addr, [value])
            return pdu
        if fc == 16:
            if len(pdu) < 6:
                raise ModbusException(3)
            addr, count, nbytes = struct.unpack(">HHB", pdu[1:6])
            if not 1 <= count <= 123 or nbytes != 2 * count or len(pdu) != 6 + nbytes:
                raise ModbusException(3)
            write(addr, list(struct.unpack(f">{count}H", pdu[6:])))
            return pdu[:5]
        raise ModbusException(1)
    except ModbusException as err:
        return bytes((fc | 0x80, err.code))
