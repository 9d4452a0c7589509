"""argparse ``type=`` functions for every numeric option of the ``hystbench`` commands.

A number the physics cannot take (a zero frequency, a negative duration, NaN, inf) is refused
while the command line is parsed, so argparse prints usage and one line naming the option
(``argument --freq: must be a finite number > 0, got '0'``) and exits with status 2, before any
file is opened or instrument touched.  Every command module takes its numbers through here.
"""

from __future__ import annotations

import argparse
import math
from typing import Callable

__all__ = ["positive_float", "nonnegative_float", "finite_float", "positive_int", "nonnegative_int",
           "positive_floats", "float_in"]


def _number(text: str, what: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be {what}, got {text!r}") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"must be {what}, got {text!r}")
    return value


def finite_float(text: str) -> float:
    """Any finite number (an offset, a phase)."""
    return _number(text, "a finite number")


def positive_float(text: str) -> float:
    """A finite number > 0 (a frequency, a duration, a current amplitude, a sample rate)."""
    value = _number(text, "a finite number > 0")
    if not value > 0:
        raise argparse.ArgumentTypeError(f"must be a finite number > 0, got {text!r}")
    return value


def nonnegative_float(text: str) -> float:
    """A finite number >= 0."""
    value = _number(text, "a finite number >= 0")
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be a finite number >= 0, got {text!r}")
    return value


def float_in(lo: float, hi: float, *, lo_open: bool = True, hi_open: bool = False) -> Callable[[str], float]:
    """A finite number in an interval, e.g. ``float_in(0, 1.5)`` for (0, 1.5]."""
    span = f"{'(' if lo_open else '['}{lo:g}, {hi:g}{')' if hi_open else ']'}"

    def parse(text: str) -> float:
        value = _number(text, f"a number in {span}")
        low_ok = value > lo if lo_open else value >= lo
        high_ok = value < hi if hi_open else value <= hi
        if not (low_ok and high_ok):
            raise argparse.ArgumentTypeError(f"must be a number in {span}, got {text!r}")
        return value

    parse.__name__ = f"number in {span}"
    return parse


def _integer(text: str, what: str) -> int:
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be {what}, got {text!r}") from None


def positive_int(text: str) -> int:
    """A whole number >= 1 (a block size, a count)."""
    value = _integer(text, "a whole number >= 1")
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be a whole number >= 1, got {text!r}")
    return value


def nonnegative_int(text: str) -> int:
    """A whole number >= 0 (a seed, an index, a number of iterations)."""
    value = _integer(text, "a whole number >= 0")
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be a whole number >= 0, got {text!r}")
    return value


def positive_floats(text: str) -> list[float]:
    """A comma-separated, non-empty list of finite numbers > 0 (frequencies, amplitudes)."""
    parts = [p.strip() for p in text.split(",") if p.strip()]
    if not parts:
        raise argparse.ArgumentTypeError(f"expected comma-separated numbers > 0, got {text!r}")
    out = []
    for part in parts:
        try:
            out.append(positive_float(part))
        except argparse.ArgumentTypeError:
            raise argparse.ArgumentTypeError(f"every item must be a finite number > 0, got {part!r} in {text!r}") \
                from None
    return out
