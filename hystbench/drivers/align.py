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
        self._start_at: int | None = None  # before the first block: hand out nothing before this
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

    def contiguous(self) -> tuple[int, bool]:
        """``(n, ended)``: how many samples from the cursor every stream holds without a break (what
        the next pops hand out without a gap), and whether a break in the stream that limits them
        ends that run (it grows no more: what comes next starts with a gap).  ``(0, False)``
        before the first block (the cursor is set by the first :meth:`pop`)."""
        if self.cursor is None:
            return 0, False
        n, ended = None, False
        for q in self._q.values():
            end = self.cursor
            broken = False
            for b in q:
                if b.end_index <= end:
                    continue
                if b.first_index > end:
                    broken = True
                    break
                end = b.end_index
            if n is None or end - self.cursor < n:
                n, ended = end - self.cursor, broken
            elif end - self.cursor == n:
                ended = ended or broken
        return n or 0, ended

    def skip_to(self, index: int) -> int:
        """Hand out nothing before ``index``: dropped on purpose (samples of a bench as it was before
        a change), not a gap.  Returns how many indices that skips past the cursor (0 before the
        first block, when the start simply moves there)."""
        if self.cursor is None:
            self._start_at = max(index, self._start_at if self._start_at is not None else index)
            return 0
        skipped = max(0, index - self.cursor)
        if skipped:
            self.cursor = index
            self._drop_before(index)
        return skipped

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
            self.cursor = self.start_index = max([q[0].first_index for q in self._q.values()]
                                                 + ([] if self._start_at is None else [self._start_at]))
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
        return self.take(n)

    def take(self, n: int) -> SampleBlock:
        """The next ``n`` aligned samples as one block (views where a stream holds them in one
        piece, else joined), once every stream holds them without a break (``n`` at most
        :meth:`contiguous`'s count after a :meth:`pop`; anything else raises ValueError).  One call
        for many pops: the acquisition loop gathers blocks with it."""
        first, end = self.cursor, self.cursor + n
        channels: dict[str, np.ndarray] = {}
        flags = BlockFlags.NONE
        meta: dict[str, float] = {}
        fs_hz = 0.0
        for name, q in self._q.items():
            pieces: dict[str, list[np.ndarray]] = {}
            pos = first
            while q and pos < end:
                b = q[0]
                if b.end_index <= pos:
                    q.popleft()
                    continue
                if b.first_index > pos:
                    break
                lo, hi = pos - b.first_index, min(end, b.end_index) - b.first_index
                for c, x in b.channels.items():
                    pieces.setdefault(c, []).append(x[lo:hi])
                flags |= b.flags & ~BlockFlags.GAP
                meta.update(b.meta)
                fs_hz = b.fs_hz
                pos = b.first_index + hi
                if b.end_index <= end:
                    q.popleft()
            if pos != end:
                raise ValueError(f"aligner: {name} does not hold samples {pos}..{end} (take {n} from {first})")
            channels.update({c: v[0] if len(v) == 1 else np.concatenate(v) for c, v in pieces.items()})
        gap, self._pending_gap = self._pending_gap, 0
        if gap:
            flags |= BlockFlags.GAP
            self.gap_samples += gap
        self.cursor = end
        return SampleBlock(first, fs_hz, channels, flags=flags, gap_samples=gap, meta=meta)
