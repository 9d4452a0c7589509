"""The compensator's errors, a branch of the service's one tree (drawn in :mod:`hystbench.errors`):
all are :class:`BenchError`, so the command line turns them into exit status 2 with the message.
"""

from __future__ import annotations

from ..errors import BenchError

__all__ = ["CompensatorError", "UnreachableReference", "LearningStopped"]


class CompensatorError(BenchError):
    """A force model or the compensator cannot do what was asked."""


class UnreachableReference(CompensatorError, ValueError):
    """A force reference beyond the actuator: a negative force without a magnet, or one needing
    more current than the limit.  ``reachable_n`` is the (min, max) force that is reachable."""

    def __init__(self, message: str, reachable_n: tuple[float, float]) -> None:
        super().__init__(message)
        self.reachable_n = reachable_n


class LearningStopped(CompensatorError):
    """The learning loop stopped itself (diverging, or its command hit the current limit); the
    actuation's output was switched off before this was raised.  ``history`` holds the
    iterations run."""

    def __init__(self, message: str, history: list | None = None) -> None:
        super().__init__(message)
        self.history = list(history or [])
