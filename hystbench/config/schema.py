"""One key of a TOML file described as data: type, default, unit, range and a one-line meaning.

The checkers (``daemon.toml``, the bench file) and the reference in docs/config.md are built from
the same :class:`Key` entries, so what is documented is what is refused.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

__all__ = ["Key", "NUM", "type_name"]

#: A number: a TOML integer or float (a bool is neither).
NUM = (int, float)


def type_name(kind: Any) -> str:
    if kind == NUM:
        return "number"
    if kind is dict:
        return "table"
    return getattr(kind, "__name__", str(kind))


def _fmt(x: float) -> str:
    return f"{x:g}"


@dataclass(frozen=True)
class Key:
    """A key: ``kind`` (a type or :data:`NUM`), ``default`` (None: required), ``doc``, ``unit``,
    and its legal values: ``choices``, or numbers in a range whose lower end is ``gt`` (exclusive)
    or ``ge`` (inclusive) and upper end ``le`` (inclusive)."""

    kind: Any
    default: Any
    doc: str
    unit: str = ""
    gt: float | None = None
    ge: float | None = None
    le: float | None = None
    choices: tuple[Any, ...] | None = None

    @property
    def numeric(self) -> bool:
        return self.kind in (int, float, NUM)

    def type_problem(self, value: Any) -> str | None:
        """'must be int' and the like, or None when ``value`` has the right type."""
        if (isinstance(value, bool) and self.kind is not bool) or not isinstance(value, self.kind):
            return "must be a number" if self.kind == NUM else f"must be {type_name(self.kind)}"
        return None

    def problem(self, value: Any) -> str | None:
        """Why ``value`` is refused ('must be > 0', 'must be one of a, b', ...), or None."""
        bad = self.type_problem(value)
        if bad:
            return bad
        if self.choices is not None and value not in self.choices:
            return f"must be one of {', '.join(map(str, self.choices))}"
        if self.numeric:
            x = float(value)
            if not math.isfinite(x) or (self.gt is not None and not x > self.gt) or (
                    self.ge is not None and not x >= self.ge) or (self.le is not None and not x <= self.le):
                return f"must be {self.range_text()}"
        return None

    def range_text(self) -> str:
        """The legal values in words: '> 0', '>= 0', 'in (0, 1.5]', 'one of a, b', or ''."""
        if self.choices is not None:
            return "one of " + ", ".join(map(str, self.choices))
        low = ("(", self.gt) if self.gt is not None else ("[", self.ge) if self.ge is not None else None
        if low and self.le is not None:
            return f"in {low[0]}{_fmt(low[1])}, {_fmt(self.le)}]"
        if low:
            return f"{'>' if low[0] == '(' else '>='} {_fmt(low[1])}"
        if self.le is not None:
            return f"<= {_fmt(self.le)}"
        return ""
