"""The signal generator's SCPI command set, as data (pymeasure style), plus the few SCPI codecs
both ends need: long/short header forms, IEEE 488.2 definite-length blocks, the error queue's
``<code>,"<text>"`` replies and a message splitter that honours binary blocks.

Headers are written SCPI-style: the capitals are the short form the driver sends (``FREQ``), the
whole word the long form an instrument also accepts (``FREQuency``).  Messages end with ``\\n``.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from types import MappingProxyType
from typing import Any, Mapping

import numpy as np

__all__ = ["Control", "GENERATOR", "RST_STATE", "SCPI_ERRORS", "MAX_OUTPUT_V", "ARB_POINTS",
           "IDN_FIELDS", "short_form", "header_matches", "encode_block", "parse_error_reply",
           "format_error_reply", "dac_from_unit", "unit_from_dac", "ScpiMessageReader", "split_command"]

EOL = b"\n"
MAX_OUTPUT_V = 10.0  #: |offset| + amplitude/2 may not exceed this (into high impedance)
ARB_POINTS = (8, 65536)  #: allowed length of an arbitrary waveform, points
IDN_FIELDS = ("manufacturer", "model", "serial", "firmware")


def short_form(header: str) -> str:
    """'VOLTage:OFFSet' -> 'VOLT:OFFS'; common commands ('*RST') are their own short form."""
    return ":".join(node if node.startswith("*") else "".join(c for c in node if not c.islower())
                    for node in header.split(":"))


def header_matches(header: str, received: str) -> bool:
    """Whether ``received`` (any case, each node short or long) names ``header``."""
    want, got = header.split(":"), received.strip().split(":")
    if len(want) != len(got):
        return False
    return all(g.upper() in (short_form(w).upper(), w.upper()) for w, g in zip(want, got))


@dataclass(frozen=True)
class Control:
    """One property or action of the instrument.

    ``kind``: 'float', 'bool' (ON/OFF, queries answer 1/0), 'choice', 'block' (binary data),
    'event' (no argument, no reply) or 'text' (query only)."""

    header: str
    kind: str
    unit: str = ""
    minimum: float | None = None
    maximum: float | None = None
    choices: tuple[str, ...] = ()
    settable: bool = True
    queryable: bool = True
    doc: str = ""

    @property
    def short(self) -> str:
        return short_form(self.header)

    def check(self, name: str, value: Any) -> None:
        """ValueError naming the property when a value is not allowed (before anything is sent)."""
        if self.kind == "float":
            v = float(value)
            if not np.isfinite(v) or (self.minimum is not None and v < self.minimum) or (
                    self.maximum is not None and v > self.maximum):
                raise ValueError(f"{name} = {value!r} outside [{self.minimum}, {self.maximum}] {self.unit}")
        elif self.kind == "choice" and str(value).upper() not in self.choices:
            raise ValueError(f"{name} = {value!r} not one of {self.choices}")

    def format(self, value: Any) -> str:
        if self.kind == "float":
            return f"{float(value):.10g}"
        if self.kind == "bool":
            return "ON" if value else "OFF"
        return str(value).upper()

    def set_command(self, value: Any = None) -> bytes:
        if self.kind == "event":
            return self.short.encode() + EOL
        if self.kind == "block":
            return self.short.encode() + b" " + encode_block(bytes(value)) + EOL
        return f"{self.short} {self.format(value)}".encode() + EOL

    def query_command(self) -> bytes:
        return f"{self.short}?".encode() + EOL

    def parse(self, text: str) -> Any:
        text = text.strip()
        if self.kind == "float":
            return float(text)
        if self.kind == "bool":
            if text.upper() in ("1", "ON"):
                return True
            if text.upper() in ("0", "OFF"):
                return False
            raise ValueError(f"{text!r} is not a boolean")
        if self.kind == "choice":
            if text.upper() not in self.choices:
                raise ValueError(f"{text!r} not one of {self.choices}")
            return text.upper()
        return text

    def reply(self, value: Any) -> str:
        """How an instrument answers the query for ``value``."""
        if self.kind == "bool":
            return "1" if value else "0"
        if self.kind == "float":
            return f"{float(value):.10g}"
        return str(value)


def _c(*args: Any, **kw: Any) -> Control:
    return Control(*args, **kw)


#: The generator's command table: property name -> control.  The one place its SCPI is written.
GENERATOR: Mapping[str, Control] = MappingProxyType({
    "identity": _c("*IDN", "text", settable=False, doc="maker,model,serial,firmware"),
    "reset": _c("*RST", "event", queryable=False, doc="defaults of RST_STATE; output off"),
    "clear_status": _c("*CLS", "event", queryable=False, doc="empties the error queue"),
    "error": _c("SYSTem:ERRor", "text", settable=False, doc='oldest error: <code>,"<text>"'),
    "function": _c("FUNCtion", "choice", choices=("SIN", "ARB"), doc="sine or the uploaded table"),
    "frequency_hz": _c("FREQuency", "float", "Hz", 1e-3, 1e5, doc="sine frequency or arb repetition rate"),
    "amplitude_vpp": _c("VOLTage", "float", "Vpp", 0.0, 2 * MAX_OUTPUT_V, doc="peak-to-peak"),
    "offset_v": _c("VOLTage:OFFSet", "float", "V", -MAX_OUTPUT_V, MAX_OUTPUT_V, doc="DC offset"),
    "output": _c("OUTPut", "bool", doc="output relay"),
    "arb_dac": _c("DATA:ARBitrary:DAC", "block", queryable=False,
                  doc="one period, int16 LE in [-32767, 32767] = [-1, 1] x amplitude/2 + offset"),
})

#: State after *RST (and at power-on).
RST_STATE: Mapping[str, Any] = MappingProxyType(
    {"function": "SIN", "frequency_hz": 1000.0, "amplitude_vpp": 0.1, "offset_v": 0.0, "output": False})

#: The standard SCPI error numbers this generator reports.
SCPI_ERRORS: Mapping[int, str] = MappingProxyType({
    0: "No error", -102: "Syntax error", -104: "Data type error", -108: "Parameter not allowed",
    -109: "Missing parameter", -113: "Undefined header", -161: "Invalid block data",
    -221: "Settings conflict", -222: "Data out of range", -224: "Illegal parameter value",
    -350: "Queue overflow", -410: "Query INTERRUPTED",
})

_ERR = re.compile(r'^\s*([+-]?\d+)\s*,\s*"(.*)"\s*$')


def parse_error_reply(text: str) -> tuple[int, str]:
    """'-222,"Data out of range"' -> (-222, 'Data out of range'); ValueError if not that form."""
    m = _ERR.match(text)
    if not m:
        raise ValueError(f"not an error-queue reply: {text!r}")
    return int(m.group(1)), m.group(2)


def format_error_reply(code: int, text: str | None = None) -> str:
    """A ``SYST:ERR?`` answer (``-222,"Data out of range"``, ``0,"No error"``): the
    emulator's side of the error queue the driver reads."""
    return f'{code:+d},"{SCPI_ERRORS.get(code, "Error") if text is None else text}"'.replace("+0,", "0,")


def encode_block(data: bytes) -> bytes:
    """IEEE 488.2 definite-length block: #<digits><length><data>."""
    n = str(len(data))
    if len(n) > 9:
        raise ValueError("block too long")
    return f"#{len(n)}{n}".encode() + data


def dac_from_unit(x: np.ndarray) -> bytes:
    """A waveform normalised to [-1, 1] as the DAC block's int16 LE codes (rounded)."""
    x = np.asarray(x, dtype=float)
    if x.ndim != 1 or not ARB_POINTS[0] <= x.size <= ARB_POINTS[1] or not np.all(np.abs(x) <= 1.0):
        raise ValueError(f"waveform must have {ARB_POINTS[0]}..{ARB_POINTS[1]} points in [-1, 1]")
    return np.round(x * 32767.0).astype("<i2").tobytes()


def unit_from_dac(data: bytes) -> np.ndarray:
    """The inverse of :func:`dac_from_unit`: the emulator plays back the table the driver
    uploaded."""
    codes = np.frombuffer(data, dtype="<i2")
    if len(data) % 2 or not ARB_POINTS[0] <= codes.size <= ARB_POINTS[1] or np.any(codes == -32768):
        raise ValueError("invalid DAC block")
    return codes.astype(float) / 32767.0


def split_command(message: bytes) -> tuple[str, bool, bytes]:
    """(header, is_query, argument bytes) of one program message (no terminator)."""
    head, _, arg = message.partition(b" ")
    header = head.decode("ascii", "replace").strip()
    is_query = header.endswith("?")
    return header.rstrip("?"), is_query, arg.strip() if not arg.startswith(b"#") else arg


class ScpiMessageReader:
    """Bytes in, whole program messages out: splits at ``\\n`` except inside a #-block."""

    def __init__(self, max_message: int = 1 << 20) -> None:
        self._buf = bytearray()
        self._max = max_message

    def feed(self, data: bytes) -> list[bytes]:
        self._buf += data
        out: list[bytes] = []
        while True:
            end = self._message_end()
            if end is None:
                if len(self._buf) > self._max:
                    self._buf.clear()
                return out
            msg = bytes(self._buf[:end]).rstrip(b"\r")
            del self._buf[:end + 1]
            out.append(msg)

    def _message_end(self) -> int | None:
        buf = self._buf
        nl = buf.find(EOL)
        hash_at = buf.find(b" #")
        if hash_at < 0 or (0 <= nl < hash_at):
            return nl if nl >= 0 else None
        i = hash_at + 2  # after '#'
        if len(buf) < i + 1:
            return None
        if not chr(buf[i]).isdigit() or buf[i] == ord("0"):
            return nl if nl >= 0 else None  # not a definite block: let the parser complain
        digits = buf[i] - ord("0")
        if len(buf) < i + 1 + digits:
            return None
        try:
            length = int(buf[i + 1:i + 1 + digits])
        except ValueError:
            return nl if nl >= 0 else None
        end = i + 1 + digits + length
        if len(buf) <= end:
            return None
        nl = buf.find(EOL, end)
        return nl if nl >= 0 else None


def parse_block(arg: bytes) -> bytes:
    """The data of a definite-length block argument; ValueError if malformed."""
    if len(arg) < 2 or arg[:1] != b"#" or not chr(arg[1]).isdigit() or arg[1] == ord("0"):
        raise ValueError("not a definite-length block")
    digits = arg[1] - ord("0")
    length = int(arg[2:2 + digits])
    data = arg[2 + digits:]
    if len(data) != length:
        raise ValueError(f"block announces {length} bytes, has {len(data)}")
    return data
