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
           "positive_floats", "float_in", "float_list_in", "int_in", "path_arg", "SIM_MAX_IPP_A"]

#: The largest ``--ipp`` the simulated rig takes, A-pp: twice its peak current limit
#: ``sim_backend.rig.MAX_CURRENT_A`` (not imported: parsing must not load numpy; a test checks
#: that the two agree).
SIM_MAX_IPP_A = 2e4


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


def float_list_in(lo: float, hi: float) -> Callable[[str], list[float]]:
    """A comma-separated, non-empty list of finite numbers in (lo, hi]."""
    item = float_in(lo, hi)

    def parse(text: str) -> list[float]:
        return _items(text, item, f"a number in ({lo:g}, {hi:g}]")

    parse.__name__ = f"numbers in ({lo:g}, {hi:g}]"
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


def int_in(lo: int, hi: int) -> Callable[[str], int]:
    """A whole number in [lo, hi], e.g. ``int_in(1, 1_000_000)`` for a block size."""

    def parse(text: str) -> int:
        value = _integer(text, f"a whole number in [{lo:g}, {hi:g}]")
        if not lo <= value <= hi:
            raise argparse.ArgumentTypeError(f"must be a whole number in [{lo:g}, {hi:g}], got {text!r}")
        return value

    parse.__name__ = f"whole number in [{lo:g}, {hi:g}]"
    return parse


def nonnegative_int(text: str) -> int:
    """A whole number >= 0 (a seed, an index, a number of iterations)."""
    value = _integer(text, "a whole number >= 0")
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be a whole number >= 0, got {text!r}")
    return value


def positive_floats(text: str) -> list[float]:
    """A comma-separated, non-empty list of finite numbers > 0 (frequencies, amplitudes)."""
    return _items(text, positive_float, "a finite number > 0")


def _items(text: str, item: Callable[[str], float], what: str) -> list[float]:
    """``text`` split at commas, each part through ``item`` (``what`` it must be, for the message)."""
    parts = [p.strip() for p in text.split(",") if p.strip()]
    if not parts:
        raise argparse.ArgumentTypeError(f"expected comma-separated numbers, each {what}, got {text!r}")
    out = []
    for part in parts:
        try:
            out.append(item(part))
        except argparse.ArgumentTypeError:
            raise argparse.ArgumentTypeError(f"every item must be {what}, got {part!r} in {text!r}") from None
    return out


def path_arg(text: str) -> str:
    """A file or folder name.  An empty one is refused: to ``pathlib`` it is the current folder,
    so ``--out ""`` would write into it and ``--model ""`` would quietly mean "none"."""
    if not text:
        raise argparse.ArgumentTypeError(f"must be a file or folder name, got {text!r}")
    return text
