"""A SCPI digitiser or oscilloscope as a sample source: its command set as data, the waveform
preamble, and the IEEE 488.2 definite-length block (``#<n><len><bytes>``) read with errors that
say what went wrong, naming the instrument and the command.

The generic command set (:data:`GENERIC`) is the subset the major vendors share in the
Keysight/Rigol/Siglent form (``:WAVeform:...``); a vendor whose headers differ is a small dialect
table beside it (:data:`DIALECTS`), which replaces only the rows it names.  Both the driver
(``drivers/digitiser.py``) and the emulator (``sim_backend/emulators/digitiser.py``) take every
header from here, the generator's table style (``protocols/scpi.py``): capitals are the short
form the driver sends, the whole word the long form an instrument also accepts.

The digitiser runs on the bench's common sample clock (the generator's sample clock as its
external clock), acquiring continuously; each channel's memory is read from where the last read
stopped.  The preamble says where a segment starts on that clock (``x_origin`` seconds since the
clock's zero), so the first sample index is exact, and lost memory shows as a jump in it: a gap.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Callable, Mapping

import numpy as np

from ...errors import ConnectionLost, InstrumentTimeout, ProtocolError
from .scpi import encode_block, header_matches, short_form

__all__ = ["Command", "Dialect", "GENERIC", "DIALECTS", "Preamble", "dialect", "read_block", "encode_block",
           "codes_to_volts", "volts_to_codes", "compound", "split_units", "CODE_DTYPE", "FULL_SCALE_CODE",
           "FULL_SCALE_CODES", "clipped",
           "parse_event_reply", "whole_samples", "SEGMENTED_OPS", "format_event_reply", "is_error_event",
           "ESR_ERROR_BITS"]

#: Sample codes on the wire: signed 16-bit, least significant byte first.
CODE_DTYPE = np.dtype("<i2")
#: The ends of the code range (int16: -32768 and 32767): a code at either end is an input at or past
#: full scale (clipped).  An ADC of fewer bits, left-justified in the word, tops out lower (12 bits:
#: 32752): such a scope's positive clip is flagged only if it sends the word's end when overranged.
FULL_SCALE_CODES = (int(np.iinfo(CODE_DTYPE).min), int(np.iinfo(CODE_DTYPE).max))
FULL_SCALE_CODE = FULL_SCALE_CODES[1]
MAX_BLOCK_DIGITS = 9  #: IEEE 488.2: the length has 1..9 digits


@dataclass(frozen=True)
class Command:
    """One operation: its header (``{ch}``: the channel's name), the argument sent with it (None:
    none), and whether it is a query (one reply line, or a binary block for ``data``)."""

    header: str
    argument: str | None = None
    query: bool = False
    doc: str = ""

    def message(self, channel: str = "", value: object = None) -> str:
        """The program message the driver sends (short form, no terminator)."""
        head = short_form(self.header.format(ch=channel))
        arg = (None if self.argument is None else short_form(self.argument.format(ch=channel))) \
            if value is None else str(value)
        if self.query:
            return f"{head}?"
        return head if arg is None else f"{head} {arg}"

    def matches(self, received: str, channel: str = "") -> bool:
        """Whether the header of a received message names this command (short or long, any case)."""
        return header_matches(self.header.format(ch=channel), received)


def _c(header: str, argument: str | None = None, *, query: bool = False, doc: str = "") -> Command:
    return Command(header, argument, query, doc)


#: The generic command set: operation -> command.  The one place its SCPI is written.
GENERIC: Mapping[str, Command | None] = MappingProxyType({
    "identity": _c("*IDN", query=True, doc="maker,model,serial,firmware"),
    "clear_status": _c("*CLS", doc="empties the error queue"),
    "event_status": None,  # the SCPI error queue needs no latch: SYSTem:ERRor? reads it directly
    "error": _c("SYSTem:ERRor", query=True, doc='oldest error: <code>,"<text>" (read until 0)'),
    "sample_rate": _c("ACQuire:SRATe", query=True, doc="samples per second: must equal [bench] fs_hz"),
    "clock_source": _c("ROSCillator:SOURce", "EXTernal", doc="sample clock from the bench's common clock"),
    "trigger_source": _c("TRIGger:SOURce", "EXTernal", doc="the generator's sync starts the clock's zero"),
    "format": _c("WAVeform:FORMat", "WORD", doc="16-bit signed codes"),
    "unsigned": _c("WAVeform:UNSigned", "OFF", doc="signed codes (InfiniiVision sends unsigned after *RST: read "
                   "as int16 they would be off by half scale)"),
    "byte_order": _c("WAVeform:BYTeorder", "LSBFirst", doc="least significant byte first"),
    "points_mode": _c("WAVeform:POINts:MODE", "RAW", doc="the acquisition memory, not the decimated screen record"),
    "points": _c("WAVeform:POINts", "100000", doc="most points one read returns"),
    "run": _c("RUN", doc="acquire continuously (armed: starts on the trigger)"),
    "stop": _c("STOP", doc="stop acquiring"),
    "source": _c("WAVeform:SOURce", "{ch}", doc="the channel the next preamble and data are read from"),
    # segmented acquisition (an oscilloscope: one segment per trigger, armed once per batch)
    "acquire_mode": _c("ACQuire:MODE", "SEGMented", doc="segmented memory: one record per trigger"),
    "segment_count": _c("ACQuire:SEGMented:COUNt", "16", doc="segments per batch ([digitiser] segments)"),
    "arm": _c("DIGitize", doc="acquire the batch's segments, one per trigger, then stop"),
    "wait": _c("*OPC", query=True, doc="answers 1 when the armed batch is complete (bounded by the driver)"),
    "segment_index": _c("ACQuire:SEGMented:INDex", "1", doc="the segment the next preamble, data and tag read"),
    "time_tag": _c("WAVeform:SEGMented:TTAG", query=True,
                   doc="seconds from the batch's first trigger to this segment's"),
    "preamble": _c("WAVeform:PREamble", query=True,
                   doc="the next segment of the source (latched until its data is read)"),
    "data": _c("WAVeform:DATA", query=True, doc="the segment the preamble announced, as a definite-length block"),
})


#: The operations of a segmented acquisition (a dialect lacking one cannot run it).
SEGMENTED_OPS = ("acquire_mode", "segment_count", "arm", "wait", "segment_index", "time_tag")


@dataclass(frozen=True)
class Dialect:
    """A vendor's variant: the rows of :data:`GENERIC` it replaces (None: not sent), commands sent
    once after opening, how channels are named, and the preamble's fields and separator.

    ``preamble_fields`` names every field of the reply in order; those named after a
    :class:`Preamble` attribute are read, ``encoding``'s must say what the driver reads (signed
    16-bit codes, least significant byte first: else the codes would be silently wrong), the rest
    are skipped."""

    name: str
    replaces: Mapping[str, Command | None]
    channel_names: tuple[str, ...]
    preamble_fields: tuple[str, ...]
    separator: str = ","
    on_open: tuple[str, ...] = ()
    constants: Mapping[str, str] = field(default_factory=dict)  # the other fields' values (the emulator's)
    encoding: tuple[str, ...] = ()  # fields of ``constants`` the instrument's reply must match (any case)

    def command(self, op: str) -> Command | None:
        return self.replaces[op] if op in self.replaces else GENERIC[op]

    def cmd(self, op: str) -> Command:
        """A command every dialect has (a ValueError naming the dialect, were one to lack it)."""
        c = self.command(op)
        if c is None:
            raise ValueError(f"dialect {self.name!r} has no {op!r} command")
        return c

    @property
    def segmented(self) -> bool:
        """Whether the dialect has the commands of a segmented (triggered) acquisition."""
        return all(self.command(op) is not None for op in SEGMENTED_OPS)

    @property
    def reads_events(self) -> bool:
        """Errors come from an event queue latched by ``*ESR?`` and read whole (Tektronix's
        ``*ESR?`` then ``ALLEv?``), not from ``SYSTem:ERRor?`` one entry at a time."""
        return self.command("event_status") is not None

    def channel(self, name: str) -> str:
        """The short form of the channel ``name`` names, in any SCPI spelling ('chan1', 'Channel1'
        -> 'CHAN1'): what the driver sends (the short form of a lower-case word is its digits)."""
        for canonical in self.channel_names:
            if header_matches(canonical, name):
                return short_form(canonical)
        raise ValueError(f"{name!r} is not a channel of dialect {self.name!r}")

    @property
    def commands(self) -> dict[str, Command]:
        return {op: c for op in GENERIC if (c := self.command(op)) is not None}


_KEYSIGHT_FIELDS = ("format", "type", "points", "count", "x_increment", "x_origin", "x_reference",
                    "y_increment", "y_origin", "y_reference")
_TEK_FIELDS = ("byt_nr", "bit_nr", "encdg", "bn_fmt", "byt_or", "wfid", "points", "pt_fmt", "xunit",
               "x_increment", "x_origin", "x_reference", "yunit", "y_increment", "y_reference", "y_origin")

#: Dialects by the bench file's ``[digitiser] dialect``.
DIALECTS: Mapping[str, Dialect] = MappingProxyType({
    "generic": Dialect("generic", {}, ("CHANnel1", "CHANnel2", "CHANnel3", "CHANnel4"), _KEYSIGHT_FIELDS,
                       constants=MappingProxyType({"format": "1", "type": "0", "count": "1"})),
    "tektronix": Dialect(
        "tektronix",
        {"sample_rate": _c("HORizontal:MODE:SAMPLERate", query=True),
         "clock_source": _c("ROSCillator:SOURce", "EXTernal"),
         "trigger_source": _c("TRIGger:A:EDGE:SOUrce", "AUXiliary"),
         "format": _c("DATa:ENCdg", "SRIbinary", doc="signed, least significant byte first"),
         "unsigned": None,  # SRIbinary is signed already
         "event_status": _c("*ESR", query=True, doc="the event status register: moves the events to the queue"),
         "error": _c("ALLEv", query=True, doc='every queued event: <code>,"<text>"[,<code>,"<text>"...]'),
         "byte_order": _c("WFMOutpre:BYT_Nr", "2"),
         "points_mode": None,  # CURVe? reads the record at full resolution
         "points": None,
         # FastFrame is Tektronix's segmented memory; not written here: segmented needs the generic dialect
         "acquire_mode": None, "segment_count": None, "arm": None, "wait": None, "segment_index": None,
         "time_tag": None,
         "run": _c("ACQuire:STATE", "RUN"), "stop": _c("ACQuire:STATE", "STOP"),
         "source": _c("DATa:SOUrce", "{ch}"),
         "preamble": _c("WFMOutpre", query=True),
         "data": _c("CURVe", query=True)},
        ("CH1", "CH2", "CH3", "CH4"), _TEK_FIELDS, separator=";", on_open=("HEADer OFF",),
        constants=MappingProxyType({"byt_nr": "2", "bit_nr": "16", "encdg": "BIN", "bn_fmt": "RI", "byt_or": "LSB",
                                    "wfid": '"hystbench emulation"', "pt_fmt": "Y", "xunit": '"s"',
                                    "yunit": '"V"'}),
        encoding=("byt_nr", "encdg", "bn_fmt", "byt_or")),
})


def dialect(name: str) -> Dialect:
    try:
        return DIALECTS[name]
    except KeyError:
        raise ValueError(f"unknown dialect {name!r}; known: {', '.join(DIALECTS)}") from None


@dataclass(frozen=True)
class Preamble:
    """A segment's description: ``points`` codes; point k was taken at
    ``(k - x_reference) * x_increment + x_origin`` seconds and is worth
    ``(code - y_reference) * y_increment + y_origin`` volts."""

    points: int
    x_increment: float
    x_origin: float
    x_reference: float
    y_increment: float
    y_origin: float
    y_reference: float

    def start_s(self, fs_hz: float) -> float:
        """When the first point was taken (the points checked to be one period of the clock apart,
        not decimated)."""
        if abs(self.x_increment * fs_hz - 1.0) > 1e-6:  # an instrument prints about 9 digits
            raise ValueError(f"the points are {self.x_increment!r} s apart, not one period of the {fs_hz:g} Hz "
                             "clock (a decimated or resampled read)")
        return self.x_origin - self.x_reference * self.x_increment

    def first_index(self, fs_hz: float) -> int:
        """The common-clock index of the segment's first point (exact: it must be a whole sample,
        and the points one period of the clock apart, not decimated)."""
        return whole_samples(self.start_s(fs_hz), fs_hz, "the segment starts at")

    @classmethod
    def parse(cls, text: str, d: Dialect) -> "Preamble":
        """A preamble reply in dialect ``d``; ValueError naming what is wrong."""
        parts = [p.strip() for p in text.strip().split(d.separator)]
        if len(parts) != len(d.preamble_fields):
            raise ValueError(f"preamble has {len(parts)} fields, {len(d.preamble_fields)} expected: {text.strip()!r}")
        got = dict(zip(d.preamble_fields, parts))
        for f in d.encoding:
            if got[f].upper() != d.constants[f].upper():
                raise ValueError(f"preamble says {f} = {got[f]!r}, the driver reads {d.constants[f]!r}: "
                                 f"{text.strip()!r}")
        try:
            pre = cls(int(float(got["points"])), *(float(got[f]) for f in
                                                   ("x_increment", "x_origin", "x_reference", "y_increment",
                                                    "y_origin", "y_reference")))
        except ValueError:
            raise ValueError(f"preamble field not a number: {text.strip()!r}") from None
        if pre.points < 0 or not pre.x_increment > 0 or not np.isfinite(pre.y_increment) or pre.y_increment == 0:
            raise ValueError(f"preamble out of range: {text.strip()!r}")
        return pre

    def format(self, d: Dialect) -> str:
        """The reply an instrument speaking dialect ``d`` gives (the emulator's side)."""
        mine = {"points": str(self.points), **{f: f"{getattr(self, f):.17g}" for f in
                                               ("x_increment", "x_origin", "x_reference", "y_increment",
                                                "y_origin", "y_reference")}}
        return d.separator.join(mine.get(f, d.constants.get(f, "0")) for f in d.preamble_fields)


#: *ESR? bits that mean an error: command (CME), execution (EXE), device (DDE), query (QYE).
ESR_ERROR_BITS = {0x20: "command error", 0x10: "execution error", 0x08: "device error", 0x04: "query error"}
_EVENT = re.compile(r'\s*(-?\d+)\s*,\s*"((?:[^"]|"")*)"\s*(?:,|$)')
NO_EVENTS = "No events to report - queue empty"


def parse_event_reply(text: str) -> list[tuple[int, str]]:
    """An ``ALLEv?`` reply (``0,"No events to report - queue empty"``, ``113,"Undefined header; ..."``
    or several pairs, with or without the ``:ALLEV`` header) as its events, code 0 left out;
    ValueError if it is not that form."""
    body = text.strip()
    head = body.split(" ", 1)
    if head[0].lstrip(":").upper() in ("ALLEV", "ALLE") and len(head) == 2:
        body = head[1]
    events, pos = [], 0
    while pos < len(body):
        m = _EVENT.match(body, pos)
        if m is None or m.end() == pos:
            raise ValueError(f"not an event-queue reply: {text.strip()!r}")
        events.append((int(m.group(1)), m.group(2).replace('""', '"')))
        pos = m.end()
    if not events:
        raise ValueError(f"not an event-queue reply: {text.strip()!r}")
    return [(c, t) for c, t in events if c != 0]


def format_event_reply(events: list[tuple[int, str]]) -> str:
    """The ``ALLEv?`` answer (headers off) to ``events`` (the emulator's side)."""
    if not events:
        return f'0,"{NO_EVENTS}"'
    return ",".join(f'{c},"{t.replace(chr(34), chr(34) * 2)}"' for c, t in events)


def is_error_event(code: int) -> bool:
    """Tektronix event codes 100-399 are command, execution and device errors; 400s are status
    events (e.g. 402 operation complete), 500-600s warnings."""
    return 100 <= abs(code) < 400


def whole_samples(t_s: float, fs_hz: float, what: str) -> int:
    """``t_s`` as a whole number of periods of the clock; ValueError if it falls between two."""
    k = t_s * fs_hz
    index = int(round(k))
    if abs(k - index) > 1e-3:
        raise ValueError(f"{what} {t_s!r} s, between two samples of the {fs_hz:g} Hz clock")
    return index


def compound(*messages: str) -> str:
    """Program message units as one message, each from the root: ``WAV:SOUR CHAN1;:WAV:PRE?``."""
    return ";:".join(messages)


def split_units(message: bytes) -> list[bytes]:
    """The units of a program message (``;``-separated; a leading ``:`` is the root).  A unit
    without one continues the previous unit's header path (``WAV:SOUR CHAN1;PRE?`` is
    ``WAV:PRE?``).  Digitiser messages carry no blocks or strings, so ``;`` always separates."""
    out: list[bytes] = []
    path = b""
    for unit in message.split(b";"):
        unit = unit.strip()
        if not unit:
            continue
        if unit.startswith(b":"):
            unit = unit[1:]
        elif not unit.startswith(b"*") and path:
            unit = path + unit
        head = unit.split(b" ", 1)[0]
        if not head.startswith(b"*"):
            path = head[:head.rfind(b":") + 1]
        out.append(unit)
    return out


def codes_to_volts(codes: np.ndarray, pre: Preamble) -> np.ndarray:
    return (codes.astype(np.float64) - pre.y_reference) * pre.y_increment + pre.y_origin


def volts_to_codes(volts: np.ndarray, y_increment: float) -> tuple[np.ndarray, bool]:
    """Volts as the ADC's codes (rounded, clipped at full scale); True if any clipped."""
    lo, hi = FULL_SCALE_CODES
    k = np.round(np.asarray(volts, dtype=np.float64) / y_increment)
    return np.clip(k, lo, hi).astype(CODE_DTYPE), bool(np.any((k < lo) | (k > hi)))


def clipped(codes: np.ndarray) -> bool:
    """Whether any code is at an end of the code range (the input at or past full scale)."""
    lo, hi = FULL_SCALE_CODES
    return bool(codes.size) and bool(np.any((codes <= lo) | (codes >= hi)))


def read_block(read: Callable[[int], bytes], where: str, *, max_bytes: int = 1 << 28) -> bytes:
    """One IEEE 488.2 definite-length block read through ``read(n)`` (exactly n bytes, or raises
    TimeoutError), then its terminator ``\\n``.  ``where`` names instrument and command in errors:
    ProtocolError for a malformed block (a wrong mark or length digit, a length that is not a
    number, a missing terminator after the data: bytes counted wrongly, a truncated block), and
    InstrumentTimeout saying how many bytes of the block had come.  Nothing is filled in."""
    got = 0

    def take(n: int, what: str) -> bytes:
        nonlocal got
        try:
            data = read(n)
        except TimeoutError as err:
            raise InstrumentTimeout(f"{where}: timed out in the binary block after {got} bytes, "
                                    f"waiting for {what}") from err
        except ConnectionError as err:
            raise ConnectionLost(f"{where}: the connection closed in the binary block after {got} bytes, "
                                 f"waiting for {what}") from err
        got += len(data)
        return data

    head = take(2, "its header '#<n>'")
    if head[:1] != b"#":
        raise ProtocolError(f"{where}: expected a definite-length block '#<n><length><data>', got {head!r}")
    if not (head[1:2].isdigit() and head[1:2] != b"0"):
        what = "an indefinite-length block ('#0') is not accepted" if head[1:2] == b"0" else \
            f"length digit {head[1:2]!r} is not 1..{MAX_BLOCK_DIGITS}"
        raise ProtocolError(f"{where}: bad block header {head!r}: {what}")
    digits = int(head[1:2])
    length_text = take(digits, f"the {digits} length digits")
    if not length_text.isdigit():
        raise ProtocolError(f"{where}: block length {length_text!r} ({digits} digits announced) is not a number")
    length = int(length_text)
    if length > max_bytes:
        raise ProtocolError(f"{where}: block announces {length} bytes, more than the {max_bytes} accepted")
    data = take(length, f"{length} data bytes") if length else b""
    end = take(1, "the terminator after the data")
    if end != b"\n":
        raise ProtocolError(f"{where}: no terminator after the {length} bytes the block announced (got {end!r}): "
                            f"the length does not match the data")
    return data
