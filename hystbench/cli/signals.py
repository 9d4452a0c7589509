"""A signal turned into the interrupt Ctrl-C raises, and noted: the code that cleans up on Ctrl-C
(staged outputs, open logs) runs for it too, and the command knows which signal came."""

from __future__ import annotations

import signal
import threading
from contextlib import contextmanager
from typing import Iterator

__all__ = ["noting"]


@contextmanager
def noting(signum: int) -> Iterator[list[bool]]:
    """A list that holds True once ``signum`` came while the block ran; the signal raises
    KeyboardInterrupt in the main thread, as Ctrl-C does.  Off the main thread (no signals reach it)
    the list stays empty; a handler a command installs inside the block replaces this one."""
    seen: list[bool] = []
    if threading.current_thread() is not threading.main_thread():
        yield seen
        return

    def note(signum: int, frame: object) -> None:
        seen.append(True)
        raise KeyboardInterrupt

    before = signal.signal(signum, note)
    try:
        yield seen
    finally:
        signal.signal(signum, before)
