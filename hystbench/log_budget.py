"""One way to keep a repeated log line from flooding the log: a :class:`LogBudget` per kind of line.

A hostile or broken client can repeat a refused command as fast as the network carries it; one
warning line each (a 20 000-command flood wrote 19 887 lines) makes the daemon's log grow with the
flood.  The budget logs the first ``per_window`` lines of each window, counts the rest, and says how
many it held back in one line when the next window opens (or when asked, at the end)::

    turn = budget.admit()
    if turn.held:                      # lines held back in the window before: one line for them
        log.warning("%d more ... not logged one by one", turn.held)
    if turn.log:
        log.warning("cmd/%s refused: %s%s", verb, why, HELD_NOTE if turn.last else "")

The clock is injectable (``clock=``), so the budget is tested without sleeping.
Vocabulary layer: standard library only.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass
from typing import Callable

__all__ = ["LogBudget", "Turn"]


@dataclass(frozen=True)
class Turn:
    """What to do with one occurrence: ``log`` it (``last``: the window's last line, say that the
    rest are counted); ``held``: lines held back in the window before, to report first."""

    log: bool
    last: bool
    held: int


class LogBudget:
    """At most ``per_window`` lines per ``window_s`` (thread-safe: zenoh calls from its threads)."""

    def __init__(self, per_window: int = 10, window_s: float = 1.0, *,
                 clock: Callable[[], float] = time.monotonic) -> None:
        if per_window < 1 or not window_s > 0:
            raise ValueError(f"a log budget needs per_window >= 1 and window_s > 0, got {per_window}, {window_s}")
        self.per_window, self.window_s, self._clock = int(per_window), float(window_s), clock
        self._lock = threading.Lock()
        self._start: float | None = None
        self._used = 0
        self._held = 0

    def admit(self, *, always: bool = False) -> Turn:
        """The next occurrence's turn; ``always``: it is logged whatever the budget (the first of its
        kind, with its traceback), and uses up a line of it."""
        with self._lock:
            now = self._clock()
            held = 0
            if self._start is None or now - self._start >= self.window_s:
                held, self._held = self._held, 0
                self._start, self._used = now, 0
            if self._used < self.per_window or always:
                self._used += 1
                return Turn(True, self._used == self.per_window, held)
            self._held += 1
            return Turn(False, False, held)

    def take_held(self) -> int:
        """Lines held back and not yet reported (reported now by the caller: at close)."""
        with self._lock:
            held, self._held = self._held, 0
            return held
