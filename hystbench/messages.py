"""The live path's messages as types: the operating point a block was played at, the estimate
of one window, and what a compensator's update asks of the pipeline (:class:`CompensatorUpdate`:
its published state apart from its commands; the one of the three not written as JSON).

The first two are frozen dataclasses in SI units with the unit in each name (``frequency_hz``,
``current_pp_a``, ``delays_s``), and both read and write JSON symmetrically, as mcap's records do:
``X.from_json(x.to_json()) == x``.  ``to_json`` gives plain Python values named as the fields;
NaN stays NaN there, :func:`json_bytes` (the bytes of every small message, in the MCAP log and on
zenoh alike) writes it as ``null`` (NaN is not JSON) and ``from_json`` reads ``null`` back as NaN.  :func:`json_schema` derives the JSON schema the MCAP
log registers from the fields, so the schema cannot drift from the class.

A block keeps its operating point in ``SampleBlock.meta`` as a flat mapping of numbers (what the
raw-block codec writes and old logs hold); code builds that mapping only through
:meth:`OperatingPoint.to_meta`, and reads it as the block's typed ``SampleBlock.point`` (read once per
block by :meth:`OperatingPoint.from_meta`; None for a block whose meta names no operating point).

The recording sidecar (``frequency_Hz``, ``current_pp_A``, ``sample_rate_Hz``) is the interchange
format's spelling: it is translated in :mod:`hystbench.formats.recording` only, never here.
"""

from __future__ import annotations

import collections.abc
import functools
import json
import math
import types
import typing
from dataclasses import MISSING, dataclass, field, fields
from typing import Any, ClassVar, Mapping

import numpy as np

from .errors import RecordingError

__all__ = ["OperatingPoint", "UNKNOWN_POINT", "Estimate", "CompensatorUpdate", "OPERATING_KEYS", "json_schema",
           "json_bytes", "json_text"]

#: Block meta keys that name the operating point (the fields of :class:`OperatingPoint`, in order):
#: a change of any of them starts a new run of the estimator and a new segment of a log.
OPERATING_KEYS = ("frequency_hz", "current_pp_a", "offset_a", "output_on", "settling", "table")


def _doc(text: str) -> dict[str, str]:
    return {"doc": text}


# --- JSON of the fields, both ways ----------------------------------------------------------------
_UNIONS = (typing.Union, types.UnionType)
_MAPPINGS = (dict, collections.abc.Mapping)


@functools.cache
def _hints(cls: type) -> dict[str, Any]:
    return typing.get_type_hints(cls)


def _out(value: Any) -> Any:
    """A field value as plain JSON-able Python (mappings to dicts, tuples to lists)."""
    if isinstance(value, Mapping):
        return {str(k): _out(v) for k, v in value.items()}
    if isinstance(value, (tuple, list)):
        return [_out(v) for v in value]
    return value


def _read(hint: Any, value: Any, where: str) -> Any:
    """``value`` (decoded JSON) as the field type ``hint``; a mismatch is a ValueError naming ``where``."""
    origin = typing.get_origin(hint)
    if hint is float:
        if value is None:
            return math.nan
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ValueError(f"{where} must be a number, got {value!r}")
        return float(value)
    if hint is int:
        if isinstance(value, bool) or not isinstance(value, int):
            if isinstance(value, float) and value.is_integer():
                return int(value)
            raise ValueError(f"{where} must be an integer, got {value!r}")
        return value
    if hint is bool:
        if not isinstance(value, bool):
            raise ValueError(f"{where} must be true or false, got {value!r}")
        return value
    if hint is str:
        if not isinstance(value, str):
            raise ValueError(f"{where} must be a string, got {value!r}")
        return value
    if origin in _UNIONS:  # X | None
        args = [a for a in typing.get_args(hint) if a is not type(None)]
        return None if value is None else _read(args[0], value, where)
    if origin in _MAPPINGS:
        _, vt = typing.get_args(hint)
        if not isinstance(value, Mapping):
            raise ValueError(f"{where} must be an object, got {value!r}")
        return {str(k): _read(vt, v, f"{where}[{k!r}]") for k, v in value.items()}
    if origin is tuple:
        (vt, _) = typing.get_args(hint)
        if not isinstance(value, (list, tuple)):
            raise ValueError(f"{where} must be an array, got {value!r}")
        return tuple(_read(vt, v, f"{where}[{i}]") for i, v in enumerate(value))
    raise TypeError(f"no JSON reading for {hint!r}")  # a field type this module does not know: a bug


def json_bytes(obj: Any) -> bytes:
    """A small message (``to_json()``, a status, a reply) as compact JSON bytes: NaN and inf, which
    JSON has no numbers for, become ``null``; numpy scalars become Python numbers."""
    return json.dumps(_finite(obj), separators=(",", ":"), allow_nan=False).encode()


def json_text(obj: Any, indent: int | None = 2) -> str:
    """``obj`` as JSON text for a person or a script (``--json``): NaN and inf as ``null``, as in
    :func:`json_bytes` (a bare NaN is no JSON; strict parsers refused a replay's output)."""
    return json.dumps(_finite(obj), indent=indent, allow_nan=False)


def _finite(obj: Any) -> Any:
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {str(k): _finite(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_finite(v) for v in obj]
    if isinstance(obj, np.generic):
        return _finite(obj.item())
    return obj


def _from_json(cls: type, obj: Any, what: str) -> Any:
    if not isinstance(obj, Mapping):
        raise RecordingError(f"{what}: must be a JSON object, got {type(obj).__name__}")
    hints, kw = _hints(cls), {}
    for f in fields(cls):
        if f.name not in obj:
            if f.default is MISSING and f.default_factory is MISSING:
                raise RecordingError(f"{what}: missing key {f.name!r}")
            continue
        try:
            kw[f.name] = _read(hints[f.name], obj[f.name], f"key {f.name!r}")
        except ValueError as err:
            raise RecordingError(f"{what}: {err}") from err
    return cls(**kw)


def _schema_of(hint: Any) -> dict[str, Any]:
    origin = typing.get_origin(hint)
    if hint is float:
        return {"type": ["number", "null"]}  # NaN is written as null
    if hint is int:
        return {"type": "integer"}
    if hint is bool:
        return {"type": "boolean"}
    if hint is str:
        return {"type": "string"}
    if origin in _UNIONS:  # X | None
        args = [a for a in typing.get_args(hint) if a is not type(None)]
        inner = _schema_of(args[0])
        return {**inner, "type": [inner["type"], "null"]} if isinstance(inner["type"], str) else inner
    if origin is tuple:
        return {"type": "array", "items": _schema_of(typing.get_args(hint)[0])}
    if origin in _MAPPINGS:
        return {"type": "object", "additionalProperties": _schema_of(typing.get_args(hint)[1])}
    raise TypeError(f"no JSON schema for {hint!r}")


def json_schema(cls: type, title: str, description: str = "") -> dict[str, Any]:
    """The JSON schema of ``cls.to_json()``: one property per field (its type, its ``doc``), the
    fields without a default required."""
    hints = _hints(cls)
    props = {}
    for f in fields(cls):
        doc = {"description": f.metadata["doc"]} if "doc" in f.metadata else {}
        props[f.name] = {**_schema_of(hints[f.name]), **doc}
    required = [f.name for f in fields(cls) if f.default is MISSING and f.default_factory is MISSING]
    schema = {"title": title, "type": "object", "properties": props, "required": required}
    if description:
        schema["description"] = description
    return schema


# --- the operating point --------------------------------------------------------------------------------
@dataclass(frozen=True)
class OperatingPoint:
    """What the generator played while a block was sampled (the sources set it on every block).

    ``settling`` marks samples that may still be from before the last command (instruments apply
    it somewhere in their stream's latency); ``table`` counts the changes of what the generator
    plays (a sine set, a waveform uploaded), so samples with one count were played with one
    waveform."""

    frequency_hz: float = field(metadata=_doc("nominal excitation frequency, Hz"))
    current_pp_a: float = field(metadata=_doc("nominal peak-to-peak excitation current, A"))
    offset_a: float = field(default=0.0, metadata=_doc("DC offset of the current, A"))
    output_on: bool = field(default=True, metadata=_doc("the amplifier's output is on"))
    settling: bool = field(default=False, metadata=_doc("samples that may predate the last command"))
    table: int = field(default=0, metadata=_doc("count of changes of what the generator plays"))

    SCHEMA_TITLE: ClassVar[str] = "hystbench.OperatingPoint"

    @property
    def excited(self) -> bool:
        """Output on and settled: samples an estimate may use."""
        return self.output_on and not self.settling

    @property
    def peak_a(self) -> float:
        """The peak coil current the point drives with the output on, ``|offset| + I_pp / 2``: what
        a bench's current limit bounds (acquisition.bench_commands checks every command by it)."""
        return abs(self.offset_a) + self.current_pp_a / 2

    def to_meta(self) -> dict[str, float]:
        """The point as block meta: numbers only (``output_on`` 1.0/0.0; ``settling`` only when
        set), as the raw-block codec writes it and logs since the first have held it."""
        meta = {"frequency_hz": float(self.frequency_hz), "current_pp_a": float(self.current_pp_a),
                "offset_a": float(self.offset_a), "output_on": 1.0 if self.output_on else 0.0,
                "table": float(self.table)}
        if self.settling:
            meta["settling"] = 1.0
        return meta

    @classmethod
    def from_meta(cls, meta: Mapping[str, Any], default: "OperatingPoint | None" = None) -> "OperatingPoint":
        """The point a block's meta names; keys it lacks are ``default``'s (the source's nominal
        point), or the field defaults with NaN frequency, current and offset when there is none."""
        d = UNKNOWN_POINT if default is None else default
        get = meta.get
        f, ipp, off, on, settling, table = (get(k) for k in OPERATING_KEYS)  # the fields, in order
        return cls(d.frequency_hz if f is None else float(f),
                   d.current_pp_a if ipp is None else float(ipp),
                   d.offset_a if off is None else float(off),
                   d.output_on if on is None else on != 0.0,
                   d.settling if settling is None else bool(settling),
                   d.table if table is None else int(table))

    def to_json(self) -> dict[str, Any]:
        return {f.name: _out(getattr(self, f.name)) for f in fields(self)}

    @classmethod
    def from_json(cls, obj: Any) -> "OperatingPoint":
        return _from_json(cls, obj, "operating point message")

    @classmethod
    def json_schema(cls) -> dict[str, Any]:
        return json_schema(cls, cls.SCHEMA_TITLE, "The operating point a block was played at")


#: What a block whose meta names no operating point says: frequency, current and offset not known (NaN).
UNKNOWN_POINT = OperatingPoint(math.nan, math.nan, math.nan)


# --- the estimate ------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Estimate:
    """The method's delays over one window of whole periods, ``[first_index, end_index)`` in source
    sample indices (positive delay: the later-named signal lags; hysteresis = flux behind current,
    instrument = force behind flux, total = force behind current; at 2f without magnet).

    A window the method refuses has ``error`` set and no delays.  ``outliers`` names, by source
    sample index, the samples left out of the fits as gross outliers (channel -> indices)."""

    first_index: int = field(metadata=_doc("source sample index of the window's first sample"))
    end_index: int = field(metadata=_doc("source sample index one past the window's last sample"))
    t_ns: int = field(metadata=_doc("log time of end_index, ns"))
    nominal_frequency_hz: float = field(metadata=_doc("the operating point's frequency, Hz"))
    current_pp_a: float = field(metadata=_doc("the operating point's peak-to-peak current, A"))
    table: int = field(default=0, metadata=_doc("which waveform played (OperatingPoint.table)"))
    error: str | None = field(default=None, metadata=_doc("why the method refused the window"))
    frequency_hz: float = field(default=math.nan, metadata=_doc("fitted excitation frequency, Hz"))
    frequency_std_hz: float = field(default=math.nan, metadata=_doc("its standard error, Hz"))
    harmonic: int = field(default=0, metadata=_doc("the harmonic the delays are read at (1, or 2 without magnet)"))
    delays_s: Mapping[str, float] = field(default_factory=dict, metadata=_doc("delay by name, s"))
    delays_std_s: Mapping[str, float] = field(default_factory=dict, metadata=_doc("standard errors, s"))
    phases_deg: Mapping[str, float] = field(default_factory=dict,
                                            metadata=_doc("the delays as phases at frequency_hz, degrees"))
    phases_std_deg: Mapping[str, float] = field(default_factory=dict, metadata=_doc("standard errors, degrees"))
    outliers: Mapping[str, tuple[int, ...]] = field(
        default_factory=dict, metadata=_doc("samples left out of the fits, by channel (source indices)"))
    outliers_excluded: bool = field(default=False, metadata=_doc("some samples were left out as outliers"))

    SCHEMA_TITLE: ClassVar[str] = "hystbench.Estimate"

    def to_json(self) -> dict[str, Any]:
        return {f.name: _out(getattr(self, f.name)) for f in fields(self)}

    @classmethod
    def from_json(cls, obj: Any) -> "Estimate":
        return _from_json(cls, obj, "estimate message")

    @classmethod
    def json_schema(cls) -> dict[str, Any]:
        return json_schema(cls, cls.SCHEMA_TITLE, "Delays over one window of whole periods "
                                                  "(positive: the later-named signal lags)")


# --- what a compensator asks of the pipeline ----------------------------------------------------------------
@dataclass(frozen=True)
class CompensatorUpdate:
    """What one ``update`` of a compensator returns to the pipeline's hook: the state it publishes,
    and, apart from it, what the hook is to do to the source.

    ``state`` is published on the ``compensator`` topic as it is (JSON-able; nothing in it is a
    command).  ``output_off``: switch the source's output off, before anything else.
    ``waveform_a``: one period of current (A, uniformly sampled) to upload, played at
    ``frequency_hz`` (None: the estimate's nominal frequency).  Not a wire message: the commands
    are never published, the state is (with what the hook did added)."""

    state: Mapping[str, Any]
    output_off: bool = False
    waveform_a: np.ndarray | None = None
    frequency_hz: float | None = None

    def __post_init__(self) -> None:
        if self.waveform_a is not None:
            wave = np.asarray(self.waveform_a, dtype=float)
            if wave.ndim != 1 or wave.size == 0:
                raise ValueError(f"waveform_a must be one period as a 1-D array, got shape {wave.shape}")
            object.__setattr__(self, "waveform_a", wave)
