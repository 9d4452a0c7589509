"""The keys of every TOML file described as data, and the one validator that applies them.

A :class:`Key` says what one key may hold (type, default, unit, range, a one-line meaning); a
schema is a mapping of names to keys, and a key of kind ``dict`` with a ``table`` is a sub-table
with its own schema (``items``: a list, each element described by a key, tables included).
:func:`check_table` checks a file's dict against its schema: unknown keys are refused naming the
known ones, missing keys get their defaults, and every message names the file, the table and the
key.  The rig presets, the materials, the bench file and the daemon file are all checked by it,
and docs/config.md is generated from the same schemas, so what is documented is what is refused.
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass
from typing import Any, Iterator, Mapping

from ..errors import ConfigError

__all__ = ["Key", "MAX_MAGNITUDE", "NUM", "OPTIONAL", "Schema", "type_name", "check_value", "check_table", "tables"]

#: A number: a TOML integer or float (a bool is neither); checked values are floats.
NUM = (int, float)
#: The largest number any setting may take, whatever its own range: beyond every quantity of a bench
#: (a petabyte of log included), and small enough that the physics' squares and products stay finite.
MAX_MAGNITUDE = 1e15


class _Optional:
    """The default of a key that may be left out and then stays out (e.g. ``[magnet]``)."""

    def __repr__(self) -> str:
        return "OPTIONAL"


#: ``Key(..., default=OPTIONAL)``: may be left out, and is then absent from the checked dict.
#: ``default=None`` means required.
OPTIONAL: Any = _Optional()


def type_name(kind: Any) -> str:
    """A key's type as a message and docs/config.md say it (``number``, ``table``, ``str``)."""
    if kind == NUM:
        return "number"
    if kind is dict:
        return "table"
    return getattr(kind, "__name__", str(kind))


def _fmt(x: float) -> str:
    return f"{x:g}"


@dataclass(frozen=True)
class Key:
    """A key: ``kind`` (a type or :data:`NUM`), ``default`` (None: required; :data:`OPTIONAL`),
    ``doc``, ``unit`` and its legal values: ``choices``, or numbers in a range whose lower end is
    ``gt`` (exclusive) or ``ge`` (inclusive) and upper end ``lt`` (exclusive) or ``le``
    (inclusive), ``whole`` numbers only.  A ``list`` has ``items`` (the key of each element, whose
    ``doc`` is the noun messages use, e.g. "frequencies") and may have to be ``nonempty``; a
    ``dict`` with a ``table`` is a sub-table (None: any table, checked elsewhere)."""

    kind: Any
    default: Any
    doc: str
    unit: str = ""
    gt: float | None = None
    ge: float | None = None
    lt: float | None = None
    le: float | None = None
    choices: tuple[Any, ...] | None = None
    whole: bool = False
    items: "Key | None" = None
    nonempty: bool = False
    table: "Mapping[str, Key] | None" = None

    @property
    def numeric(self) -> bool:
        return self.kind in (int, float, NUM)

    @property
    def required(self) -> bool:
        return self.default is None

    def type_text(self) -> str:
        """'number', 'int', 'whole number', 'list of number', 'table', ..."""
        if self.kind is list and self.items is not None:
            return "list of " + ("tables" if self.items.kind is dict else self.items.type_text())
        return "whole number" if self.whole else type_name(self.kind)

    def type_problem(self, value: Any) -> str | None:
        """'must be int > 0' and the like (the type, with the range), or None for the right type."""
        bad = (isinstance(value, bool) and self.kind is not bool) or not isinstance(value, self.kind)
        if not bad and self.whole and not (math.isfinite(_float(value)) and float(value) == int(value)):
            bad = True
        if not bad:
            return None
        if self.kind is list and self.items is not None:
            return f"must be {self._list_text()}"
        article = "a " if self.kind in (NUM, dict) or self.whole else ""
        rng = self.range_text()
        return f"must be {article}{self.type_text()}" + (f" {rng}" if rng and self.numeric else "")

    def problem(self, value: Any) -> str | None:
        """Why ``value`` is refused ('must be > 0', 'must be one of a, b', ...), or None.  The
        elements of a list are checked against ``items``; a sub-table is :func:`check_table`'s."""
        bad = self.type_problem(value)
        if bad:
            return bad
        if self.choices is not None and value not in self.choices:
            return f"must be one of {', '.join(map(str, self.choices))}"
        if self.numeric:
            x = _float(value)
            if not math.isfinite(x):
                return f"must be {self.range_text() or 'a finite number'}"
            if abs(x) > MAX_MAGNITUDE:  # no setting of a bench is this large; 1e300 T overflowed the physics
                return f"must be {self.range_text() + ' and ' if self.range_text() else ''}at most {MAX_MAGNITUDE:g} in size"
            if (self.gt is not None and not x > self.gt) or (self.ge is not None and not x >= self.ge) or (
                    self.lt is not None and not x < self.lt) or (self.le is not None and not x <= self.le):
                return f"must be {self.range_text()}"
        if self.kind is list and self.items is not None:
            if (self.nonempty and not value) or (self.items.kind is not dict and any(
                    self.items.problem(v) for v in value)):
                return f"must be {self._list_text()}"
        return None

    def _list_text(self) -> str:
        assert self.items is not None
        noun = self.items.doc or self.items.type_text()
        rng = self.items.range_text()
        return (f"a {'non-empty ' if self.nonempty else ''}list of {noun}" + (f" {rng}" if rng else "")
                + (f" {self.items.unit}" if self.items.unit and rng else ""))

    def range_text(self) -> str:
        """The legal values in words: '> 0', '>= 0', 'in (0, 1.5]', 'one of a, b', for a list
        'non-empty, each > 0', or ''."""
        if self.choices is not None:
            return "one of " + ", ".join(map(str, self.choices))
        if self.kind is list and self.items is not None:
            each = self.items.range_text()
            return ", ".join(p for p in ("non-empty" if self.nonempty else "", f"each {each}" if each else "") if p)
        low = ("(", self.gt) if self.gt is not None else ("[", self.ge) if self.ge is not None else None
        high = (self.lt, ")") if self.lt is not None else (self.le, "]") if self.le is not None else None
        if low and high:
            return f"in {low[0]}{_fmt(low[1])}, {_fmt(high[0])}{high[1]}"
        if low:
            return f"{'>' if low[0] == '(' else '>='} {_fmt(low[1])}"
        if high:
            return f"{'<' if high[1] == ')' else '<='} {_fmt(high[0])}"
        return ""


Schema = Mapping[str, Key]


def _float(value: Any) -> float:
    """``float(value)``, an integer too large for a float being infinite (TOML's reader and JSON's
    give integers of any length, and ``float(10**400)`` raises OverflowError)."""
    try:
        return float(value)
    except OverflowError:
        return math.inf if value > 0 else -math.inf


def _place(where: str, table: str) -> str:
    return f"{where} [{table}]" if table else where


def _sub(table: str, key: str) -> str:
    return f"{table}.{key}" if table else key


def check_value(spec: Key, value: Any, where: str, table: str = "", key: str = "") -> Any:
    """``value`` checked against ``spec`` (numbers as float, whole numbers as int, sub-tables and
    lists of tables checked key by key); a ConfigError names ``where [table] key``."""
    if spec.kind is dict and spec.table is not None:
        return check_table(value, where, spec.table, _sub(table, key))
    bad = spec.problem(value)
    if bad:
        raise ConfigError(f"{_place(where, table)} {key}: {bad}, got {value!r}")
    if spec.kind is list and spec.items is not None:
        if spec.items.kind is dict and spec.items.table is not None:
            return [check_table(v, where, spec.items.table, f"{_sub(table, key)}[{i}]") for i, v in enumerate(value)]
        return [_convert(spec.items, v) for v in value]
    return _convert(spec, value)


def _convert(spec: Key, value: Any) -> Any:
    if spec.whole:
        return int(value)
    if spec.kind == NUM:
        return float(value)
    return copy.deepcopy(value) if isinstance(value, (list, dict)) else value


def check_table(data: Any, where: str, schema: Schema, table: str = "", *, key_prefix: str = "") -> dict[str, Any]:
    """``data`` checked against ``schema``: every key known, of the right type and in range, the
    missing ones filled with their defaults (:data:`OPTIONAL` ones left out, required ones
    refused).  ``where`` is the file, ``table`` the dotted path of this table in it ('' for the
    top level); ``key_prefix`` goes before each key's name in messages (e.g. 'sensor_noise.')."""
    place = _place(where, table)
    if not isinstance(data, Mapping):
        raise ConfigError(f"{place}: must be a table, got {data!r}")
    for k, v in data.items():
        if k not in schema:
            what = f"section [{_sub(table, k)}]" if isinstance(v, Mapping) else f"key {key_prefix + k!r}"
            raise ConfigError(f"{place}: unknown {what}; known: {', '.join(schema)}")
    out: dict[str, Any] = {}
    for k, spec in schema.items():
        if k in data:
            out[k] = check_value(spec, data[k], where, table, key_prefix + k)
        elif spec.default is None:
            missing = f"section [{_sub(table, k)}]" if spec.kind is dict else f"key {key_prefix + k!r}"
            raise ConfigError(f"{place}: missing {missing}")
        elif spec.kind is dict and spec.table is not None and spec.default is not OPTIONAL:
            out[k] = check_table(copy.deepcopy(spec.default), where, spec.table, _sub(table, k))
        elif spec.default is not OPTIONAL:
            out[k] = _convert(spec, copy.deepcopy(spec.default))
    return out


def tables(schema: Schema, path: str = "") -> Iterator[tuple[str, dict[str, Key], bool]]:
    """Every table of ``schema`` in file order: (dotted path, its own keys without the sub-tables,
    whether it is an array of tables ``[[path]]``); the top level is ''."""
    own = {k: v for k, v in schema.items() if not _nested(v)}
    if own or not path:
        yield path, own, False
    for k, v in schema.items():
        if v.kind is dict and v.table is not None:
            yield from tables(v.table, _sub(path, k))
        elif v.items is not None and v.items.table is not None:
            for sub, keys, _ in tables(v.items.table, _sub(path, k)):
                yield sub, keys, sub == _sub(path, k)


def _nested(k: Key) -> bool:
    return (k.kind is dict and k.table is not None) or (k.items is not None and k.items.table is not None)
