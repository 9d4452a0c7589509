"""The commands a source applies between its blocks, with output off never behind them.

A source applies what it is told (a new sine, a waveform, the output on) in its own thread,
between blocks, so that each block has one operating point.  Two things must not wait there:
switching the output off, which goes out at once from the caller's thread (the drivers lock
their transports) and cancels every ``output on`` still queued before it; and memory, which a
flood of commands would fill (each costs instrument round trips, so 100 000 queued commands held
the output on for a minute after an acknowledged off).  The queue therefore holds at most
:data:`MAX_PENDING_COMMANDS` and refuses more as busy.  Once closed, nothing more is applied: a
command in flight finishes before the close switches the output off, never after.
"""

from __future__ import annotations

import threading
from collections import deque
from typing import Callable

from ..errors import CommandRefused

__all__ = ["CommandQueue", "MAX_PENDING_COMMANDS"]

#: Commands waiting to be applied at most; a client that sends faster is told the bench is busy.
MAX_PENDING_COMMANDS = 64


class CommandQueue:
    """Commands in order, applied by :meth:`apply` (the source's thread); ``off`` switches the output
    off and may be called from any thread."""

    def __init__(self, name: str, off: Callable[[], None]) -> None:
        self.name = name
        self._off = off
        self._pending: deque[tuple[bool, Callable[[], None]]] = deque()  # (switches the output on, command)
        self._guard = threading.Lock()  # the deque and the flags
        self._applying = threading.Lock()  # held while a command or the off runs
        self._closed = False
        self._changed = False  # an off went out of turn: the source notes it as a command

    def put(self, command: Callable[[], None], *, output_on: bool = False) -> None:
        """Queue ``command``; refused (CommandRefused) when the queue is full or closed."""
        with self._guard:
            if self._closed:
                raise CommandRefused(f"{self.name}: closed, no more commands")
            if len(self._pending) >= MAX_PENDING_COMMANDS:
                raise CommandRefused(f"{self.name}: busy, {len(self._pending)} commands are waiting to be applied; "
                                     "send again when they are")
            self._pending.append((output_on, command))

    def output_off(self) -> None:
        """The output off now, in the caller's thread (after at most the command in flight), and
        every ``output on`` queued before it dropped."""
        with self._applying:
            with self._guard:
                kept = [(on, c) for on, c in self._pending if not on]
                self._pending.clear()
                self._pending.extend(kept)
                self._changed = True
            self._off()

    def apply(self) -> bool:
        """Apply what was queued when called, in order (the source's thread; what comes meanwhile waits
        for the next block, so a sustained flood cannot hold the samples up); True if anything changed
        the output or the excitation since the last call."""
        with self._guard:
            due = len(self._pending)
        applied = False
        for _ in range(due):
            with self._applying:
                with self._guard:
                    if self._closed or not self._pending:
                        break
                    _, command = self._pending.popleft()
                command()
            applied = True
        with self._guard:
            changed, self._changed = self._changed, False
        return applied or changed

    def close(self) -> None:
        """No command after this one: the queue emptied, then the output off."""
        with self._applying:
            with self._guard:
                self._closed = True
                self._pending.clear()
            self._off()
