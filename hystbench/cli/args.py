"""argparse ``type=`` functions for every numeric option of the ``hystbench`` commands.

A number the physics cannot take (a zero frequency, a negative duration, NaN, inf) is refused
while the command line is parsed, so argparse prints usage and one line naming the option
(``argument --freq: must be a finite number > 0, got '0'``) and exits with status 2, before any
file is opened or instrument touched.  Every command module takes its numbers through here.
"""

from __future__ import annotations

import argparse
import math
import os
from typing import Callable

from ..config.schema import MAX_MAGNITUDE, Key

__all__ = ["positive_float", "nonnegative_float", "finite_float", "positive_int", "nonnegative_int",
           "positive_floats", "float_in", "float_list_in", "int_in", "path_arg", "SIM_MAX_IPP_A"]

#: The largest ``--ipp`` the simulated rig takes, A-pp: twice its peak current limit
#: ``sim_backend.rig.MAX_CURRENT_A`` (not imported: parsing must not load numpy; a test checks
#: that the two agree).
SIM_MAX_IPP_A = 2e4


def _parser(key: Key, noun: str) -> Callable[[str], float]:
    """An argparse type for one number whose legal range is ``key`` (the one validator's, so the
    command line and the TOML files refuse alike); ``noun`` names it in the message."""
    what = f"{noun} {key.range_text()}".strip()
    convert = int if key.kind is int else float

    def parse(text: str) -> float:
        try:
            value = convert(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"must be {what}, got {text!r}") from None
        if key.problem(value):
            size = math.isfinite(value) and abs(value) > MAX_MAGNITUDE  # in range, and beyond any bench's
            raise argparse.ArgumentTypeError(f"must be {what}{f' and at most {MAX_MAGNITUDE:g}' if size else ''}, "
                                             f"got {text!r}")
        return value

    parse.__name__ = what.removeprefix("a ")
    return parse


finite_float = _parser(Key(float, None, "an offset, a phase"), "a finite number")
positive_float = _parser(Key(float, None, "a frequency, a duration, an amplitude, a sample rate", gt=0.0),
                         "a finite number")
nonnegative_float = _parser(Key(float, None, "", ge=0.0), "a finite number")
positive_int = _parser(Key(int, None, "a block size, a count", ge=1), "a whole number")
nonnegative_int = _parser(Key(int, None, "a seed, an index, a number of iterations", ge=0), "a whole number")


def float_in(lo: float, hi: float, *, lo_open: bool = True, hi_open: bool = False) -> Callable[[str], float]:
    """A finite number in an interval, e.g. ``float_in(0, 1.5)`` for (0, 1.5]."""
    return _parser(Key(float, None, "", gt=lo if lo_open else None, ge=None if lo_open else lo,
                       lt=hi if hi_open else None, le=None if hi_open else hi), "a number")


def float_list_in(lo: float, hi: float) -> Callable[[str], list[float]]:
    """A comma-separated, non-empty list of finite numbers in (lo, hi]."""
    item = float_in(lo, hi)

    def parse(text: str) -> list[float]:
        return _items(text, item, f"a number in ({lo:g}, {hi:g}]")

    parse.__name__ = f"numbers in ({lo:g}, {hi:g}]"
    return parse


def int_in(lo: int, hi: int) -> Callable[[str], int]:
    """A whole number in [lo, hi], e.g. ``int_in(1, 1_000_000)`` for a block size."""
    return _parser(Key(int, None, "", ge=lo, le=hi), "a whole number")


def positive_floats(text: str) -> list[float]:
    """A comma-separated, non-empty list of finite numbers > 0 (frequencies, amplitudes)."""
    return _items(text, positive_float, "a finite number > 0")


def _items(text: str, item: Callable[[str], float], what: str) -> list[float]:
    """``text`` split at commas, each part through ``item`` (``what`` it must be, for the message).
    An empty item (``80,,160``, ``80,``) is refused, not skipped: it is a number left out, and
    leaving it out would run one point fewer than the operator typed."""
    parts = [p.strip() for p in text.split(",")]
    if not any(parts):
        raise argparse.ArgumentTypeError(f"expected comma-separated numbers, each {what}, got {text!r}")
    out = []
    for k, part in enumerate(parts, 1):
        if not part:
            raise argparse.ArgumentTypeError(f"item {k} of {text!r} is empty; every item must be {what}")
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
    if os.path.exists(text) and not (os.path.isfile(text) or os.path.isdir(text)):  # a FIFO with no writer
        raise argparse.ArgumentTypeError(f"{text!r} is not a file or folder (a pipe or device: it would be "
                                         "waited on, not read)")
    return text
