"""Alignment of several instruments' streams on the common sample clock.

Every stream's first-sample index counts the same clock, so aligning is bookkeeping, not
resampling: an aligned block holds every channel at the same indices.  Where any one stream is
missing samples, the aligned output skips those indices and says so exactly (``BlockFlags.GAP``,
``gap_samples``); samples before the index where all streams have begun are not a gap.  Known
per-instrument skews travel in ``meta`` (``skew_s.<channel>``) so later stages can correct them.
"""

from __future__ import annotations

import collections
from typing import Iterable

import numpy as np

from ..blocks import BlockFlags, SampleBlock

__all__ = ["StreamAligner"]


def _tail(block: SampleBlock, k: int) -> SampleBlock:
    """``block`` without its first k samples (and without its GAP flag, which belongs to its start)."""
    return SampleBlock(block.first_index + k, block.fs_hz, {c: x[k:] for c, x in block.channels.items()},
                       flags=block.flags & ~BlockFlags.GAP, meta=block.meta)


class StreamAligner:
    """The instruments' blocks in, blocks with every channel at the same indices out (see the module
    docstring); one aligner for the bench, so every caller gets the same alignment."""

    def __init__(self, names: Iterable[str]) -> None:
        self.names = list(names)
        self._q: dict[str, collections.deque[SampleBlock]] = {n: collections.deque() for n in self.names}
        self.cursor: int | None = None  # next aligned index to emit
        self.start_index: int | None = None
        self.gap_samples = 0  # total indices skipped after the start
        self._pending_gap = 0

    def push(self, name: str, block: SampleBlock) -> None:
        if block.n:
            self._q[name].append(block)

    def queued(self) -> dict[str, int]:
        """Samples each stream holds here that are not handed out yet (at or after the cursor)."""
        c = -(1 << 62) if self.cursor is None else self.cursor
        return {n: sum(max(0, b.end_index - max(b.first_index, c)) for b in q) for n, q in self._q.items()}

    def ends(self) -> dict[str, int | None]:
        """One past each stream's newest sample held here (None: holds nothing)."""
        return {n: (q[-1].end_index if q else None) for n, q in self._q.items()}

    def waiting_for(self) -> str:
        """The stream the next aligned block waits on: the one whose samples end earliest."""
        ends = self.ends()
        return min(self.names, key=lambda n: -(1 << 62) if ends[n] is None else ends[n])

    def _drop_before(self, index: int) -> None:
        for q in self._q.values():
            while q and q[0].end_index <= index:
                q.popleft()
            if q and q[0].first_index < index:
                q[0] = _tail(q[0], index - q[0].first_index)

    def pop(self, max_samples: int | None = None) -> SampleBlock | None:
        """The next block that every stream covers, or None until they all have data there."""
        if any(not q for q in self._q.values()):
            return None
        if self.cursor is None:
            self.cursor = self.start_index = max(q[0].first_index for q in self._q.values())
        while True:
            self._drop_before(self.cursor)
            if any(not q for q in self._q.values()):
                return None
            head = max(q[0].first_index for q in self._q.values())
            if head == self.cursor:
                break
            self._pending_gap += head - self.cursor  # some stream has nothing at the cursor
            self.cursor = head
        n = min(q[0].n for q in self._q.values())
        if max_samples is not None:
            n = min(n, max_samples)
        channels: dict[str, np.ndarray] = {}
        flags = BlockFlags.NONE
        meta: dict[str, float] = {}
        for q in self._q.values():
            b = q[0]
            channels.update({c: x[:n] for c, x in b.channels.items()})
            flags |= b.flags & ~BlockFlags.GAP
            meta.update(b.meta)
        gap, self._pending_gap = self._pending_gap, 0
        if gap:
            flags |= BlockFlags.GAP
            self.gap_samples += gap
        out = SampleBlock(self.cursor, next(iter(self._q.values()))[0].fs_hz, channels, flags=flags,
                          gap_samples=gap, meta=meta)
        self.cursor += n
        return out
