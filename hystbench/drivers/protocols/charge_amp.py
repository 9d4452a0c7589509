"""The charge amplifier's RS-232 ASCII command set (Kistler 5070 class), as ONE table.

The real 5070 manual was not at hand when this was written: the mnemonics below are placeholders
with the right shape (two letters, optional argument, CR-terminated).  To match a real unit, edit
``COMMANDS`` (and, if its replies differ, ``OK``/``ERROR``); neither the driver nor the emulator
spells a mnemonic anywhere else.

Every command gets one reply line: a value for a query, ``OK`` or ``E<nn>`` for a setting.
"""

from __future__ import annotations

from dataclasses import dataclass
from types import MappingProxyType
from typing import Any, Mapping

__all__ = ["Mnemonic", "COMMANDS", "EOL", "OK", "ERRORS", "STATUS", "TIME_CONSTANTS_S", "MODES",
           "FULL_SCALE_V", "error_reply", "parse_reply_error"]

EOL = b"\r"
OK = "OK"
FULL_SCALE_V = 10.0  #: output range; beyond it the amplifier clips and flags OVERLOAD
MODES = ("RESET", "OPERATE")
#: Nominal time constants.  LONG is DC-coupled (quasi-static) in this model.
TIME_CONSTANTS_S: Mapping[str, float | None] = MappingProxyType({"SHORT": 1.0, "MEDIUM": 100.0, "LONG": None})
ERRORS: Mapping[int, str] = MappingProxyType({
    1: "unknown command", 2: "value out of range", 3: "malformed value", 4: "not allowed while operating"})
STATUS: Mapping[str, int] = MappingProxyType({"OPERATE": 0x01, "OVERLOAD": 0x02, "OVERLOAD_LATCHED": 0x04})


@dataclass(frozen=True)
class Mnemonic:
    """``set`` and ``query`` are the exact strings sent (``{}`` takes the value)."""

    set: str | None = None
    query: str | None = None
    kind: str = "event"  # 'event', 'float', 'choice', 'int', 'text'
    unit: str = ""
    minimum: float | None = None
    maximum: float | None = None
    choices: tuple[str, ...] = ()
    doc: str = ""

    def check(self, name: str, value: Any) -> None:
        if self.kind == "float":
            v = float(value)
            if not (self.minimum is None or v >= self.minimum) or not (self.maximum is None or v <= self.maximum):
                raise ValueError(f"{name} = {value!r} outside [{self.minimum}, {self.maximum}] {self.unit}")
        elif self.kind == "choice" and str(value).upper() not in self.choices:
            raise ValueError(f"{name} = {value!r} not one of {self.choices}")

    def format(self, value: Any) -> str:
        return f"{float(value):.6g}" if self.kind == "float" else str(value).upper()

    def set_command(self, value: Any = None) -> bytes:
        assert self.set is not None
        return (self.set.format(self.format(value)) if "{}" in self.set else self.set).encode() + EOL

    def query_command(self) -> bytes:
        assert self.query is not None
        return self.query.encode() + EOL

    def parse(self, text: str) -> Any:
        text = text.strip()
        if self.kind == "float":
            return float(text)
        if self.kind == "int":
            return int(text, 0)
        if self.kind == "choice":
            if text.upper() not in self.choices:
                raise ValueError(f"{text!r} not one of {self.choices}")
            return text.upper()
        return text


#: property -> mnemonic.  THE table to replace with the real manual's commands.
COMMANDS: Mapping[str, Mnemonic] = MappingProxyType({
    "identity": Mnemonic(query="ID?", kind="text", doc="model,serial,firmware"),
    "reset": Mnemonic(set="RS", doc="short the range capacitor: output 0 V; clears OVERLOAD"),
    "operate": Mnemonic(set="OP", doc="measure; clears OVERLOAD"),
    "mode": Mnemonic(query="MO?", kind="choice", choices=MODES),
    "sensitivity_pc_per_n": Mnemonic("SE {}", "SE?", "float", "pC/N", 0.01, 9999.0,
                                     doc="load-cell sensitivity the amplifier assumes"),
    "scale_n_per_v": Mnemonic("SC {}", "SC?", "float", "N/V", 1e-3, 1e6, doc="output scale (range)"),
    "time_constant": Mnemonic("TC {}", "TC?", "choice", choices=tuple(TIME_CONSTANTS_S),
                              doc="SHORT / MEDIUM high-pass; LONG is DC-coupled"),
    "lowpass_hz": Mnemonic("LP {}", "LP?", "float", "Hz", 0.0, 100_000.0, doc="2nd-order low-pass; 0 = off"),
    "status": Mnemonic(query="ST?", kind="int", doc="STATUS bits, decimal"),
})


def error_reply(code: int) -> str:
    """The amplifier's reply to a refused command (``E07``): the emulator's side of
    :func:`parse_reply_error`."""
    return f"E{code:02d}"


def parse_reply_error(text: str) -> int | None:
    """The error code of an ``E<nn>`` reply, None for anything else."""
    t = text.strip()
    if len(t) == 3 and t[0] == "E" and t[1:].isdigit():
        return int(t[1:])
    return None
