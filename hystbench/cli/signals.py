"""A signal turned into the interrupt Ctrl-C raises, and noted: the code that cleans up on Ctrl-C
(staged outputs, open logs) runs for it too, and the command knows which signal came."""

from __future__ import annotations

import signal
import sys
import threading
from contextlib import contextmanager
from typing import Iterator

__all__ = ["noting"]


@contextmanager
def noting(signum: int) -> Iterator[list[bool]]:
    """A list that holds True once ``signum`` came while the block ran; the signal raises
    KeyboardInterrupt in the main thread, as Ctrl-C does (where Python swallows it, in an import's
    callback, without a word: the caller reads the list).  Off the main thread (no signals reach it)
    the list stays empty; a handler a command installs inside the block replaces this one."""
    seen: list[bool] = []
    if threading.current_thread() is not threading.main_thread():
        yield seen
        return

    def note(signum: int, frame: object) -> None:
        seen.append(True)
        raise KeyboardInterrupt

    def quiet(unraisable: "sys.UnraisableHookArgs") -> None:  # raised in an import lock's callback: swallowed
        if not issubclass(unraisable.exc_type, KeyboardInterrupt):  # there; ``seen`` still says it came
            hook(unraisable)

    before, hook = signal.signal(signum, note), sys.unraisablehook
    sys.unraisablehook = quiet
    try:
        yield seen
    finally:
        signal.signal(signum, before)
        sys.unraisablehook = hook
