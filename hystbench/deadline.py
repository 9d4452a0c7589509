"""One way to bound a wait: a :class:`Deadline` fixed when the wait starts.

Every I/O has a timeout, and a wait that loops (a condition variable woken early, a serial port
read in short steps, a query asked again) must not restart its timeout at each turn.  The loops
that did this by hand (``deadline = monotonic() + t; left = deadline - monotonic()``) each had
their own spelling of "no timeout" and of "time is up"; this is the one.

    d = Deadline(timeout_s)            # None: wait forever
    while not ready():
        if d.expired:
            return None
        cond.wait(d.left())            # None (forever) or the seconds left, never negative
        port.timeout = d.left(0.05)    # ... or at most 0.05 s, to look again in short steps

The clock is injectable (``clock=``), so the helper is tested without sleeping.
Vocabulary layer: standard library only.
"""

from __future__ import annotations

import math
import time
from typing import Callable

__all__ = ["Deadline"]


class Deadline:
    """A point in time ``seconds`` from now (``None``: never).

    ``left()`` is what a blocking call should be given; ``expired`` says the time is up;
    ``elapsed`` is the time since the wait began (for the message that says how long it waited).
    A deadline of 0 or less is expired at once (a non-blocking look)."""

    __slots__ = ("seconds", "_clock", "_start", "_end")

    def __init__(self, seconds: float | None, *, clock: Callable[[], float] = time.monotonic) -> None:
        if seconds is not None and math.isnan(seconds):
            raise ValueError("seconds must be a number of seconds or None (no deadline), got nan")
        self.seconds = None if seconds is None else float(seconds)
        self._clock = clock
        self._start = clock()
        self._end = None if seconds is None else self._start + max(0.0, float(seconds))

    @property
    def forever(self) -> bool:
        """True for ``Deadline(None)``: it never expires."""
        return self._end is None

    def left(self, at_most: float | None = None) -> float | None:
        """Seconds left, never below 0, and at most ``at_most`` when given; ``None`` only for a
        deadline that never expires asked without ``at_most`` (``cond.wait(None)`` waits forever)."""
        if self._end is None:
            return at_most
        left = max(0.0, self._end - self._clock())
        return left if at_most is None else min(left, at_most)

    @property
    def expired(self) -> bool:
        """The time is up (never for ``Deadline(None)``)."""
        return self._end is not None and self._clock() >= self._end

    @property
    def elapsed(self) -> float:
        """Seconds since the deadline was set."""
        return self._clock() - self._start

    def __repr__(self) -> str:
        return "Deadline(None)" if self._end is None else f"Deadline({self.seconds:g} s, {self.left():.3g} s left)"
