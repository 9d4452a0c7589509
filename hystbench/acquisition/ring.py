"""A preallocated multichannel ring buffer for sample blocks: one writer, many readers.

The writer never waits.  Each reader has its own cursor; one that falls more than ``capacity``
samples behind loses the oldest ones and is told exactly how many (``RingRead.lost``, its block
flagged ``OVERRUN``), so nothing stale or torn is ever handed out as good data.  A writer that
must lose nothing (an offline replay) asks :meth:`RingBuffer.wait_for_room` first: it returns once
no reader would be lapped, counting the views a reader still holds.

- reads are views into the buffer (no copy).  A view stays intact until the writer laps it;
  ``reader.release(r)`` says afterwards whether it did (then the result computed from it must be
  dropped, and the samples count as lost).  A reader holds its last views until it releases them
  or reads again.  ``read(copy=True)`` copies and checks at once,
  trimming any samples overwritten during the copy.
- the writer moves ``_tail`` (the oldest intact position) *before* it overwrites anything, and
  publishes ``_head`` only after the copy, so a reader comparing its range against ``_tail``
  after use cannot miss an overwrite (integer attribute reads are atomic under the GIL).

Besides the samples, the ring keeps one *record* per run of contiguous source indices with the
same flags and meta (a new block that continues the last run extends it).  A read never spans
two records or the buffer's wrap point, so each returned block has one ``first_index``, exact
``gap_samples`` and the flags of its run.  At most ``max_records`` runs are kept: a stream whose
runs are shorter than ``capacity / max_records`` loses its oldest runs before the ring is full
(counted as lost like any overrun).  Positions count samples written (the ring's own
clock); ``first_index`` is the source's sample index.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass
from typing import Mapping, Sequence

import numpy as np
from numpy.typing import DTypeLike

from ..blocks import BlockFlags, SampleBlock
from ..deadline import Deadline

__all__ = ["RingBuffer", "RingReader", "RingRead"]


@dataclass(frozen=True)
class RingRead:
    """One read: ``block`` (views unless copied), samples ``lost`` just before it, ring positions."""

    block: SampleBlock
    lost: int
    start: int
    end: int

    @property
    def n(self) -> int:
        return self.end - self.start


class RingBuffer:
    """``capacity`` samples of each of ``channels`` at ``fs_hz``, stored as ``dtype``.

    >>> import numpy as np
    >>> from hystbench.blocks import SampleBlock
    >>> ring = RingBuffer(["current_A"], capacity=8, fs_hz=10.0)
    >>> r = ring.reader("doc")
    >>> ring.write(SampleBlock(0, 10.0, {"current_A": np.arange(12.0)}))
    >>> got = r.read()
    >>> got.lost, got.block.first_index, got.block.channels["current_A"].tolist()
    (4, 4, [4.0, 5.0, 6.0, 7.0])
    """

    def __init__(self, channels: Sequence[str], capacity: int, *, fs_hz: float,
                 dtype: DTypeLike = np.float32, max_records: int = 4096) -> None:
        if not channels:
            raise ValueError("channels must name at least one channel")
        if len(set(channels)) != len(channels):
            raise ValueError(f"channels must be distinct, got {list(channels)}")
        if capacity < 1 or max_records < 2:
            raise ValueError(f"capacity must be >= 1 and max_records >= 2, got {capacity}, {max_records}")
        if not fs_hz > 0:
            raise ValueError(f"fs_hz must be positive, got {fs_hz}")
        self.channels = list(channels)
        self.capacity = int(capacity)
        self.fs_hz = float(fs_hz)
        self.dtype = np.dtype(dtype)
        self._data = np.zeros((len(self.channels), self.capacity), dtype=self.dtype)
        self._row = {name: i for i, name in enumerate(self.channels)}
        m = self.max_records = int(max_records)
        self._rec_pos = np.zeros(m, dtype=np.int64)  # ring position where record k starts
        self._rec_first = np.zeros(m, dtype=np.int64)  # its source first_index
        self._rec_flags = np.zeros(m, dtype=np.int64)
        self._rec_gap = np.zeros(m, dtype=np.int64)
        self._rec_meta: list[Mapping[str, float]] = [{}] * m
        self._nrec = 0  # records ever created; record k lives in slot k % m
        self._head = 0  # samples published
        self._reserve = 0  # samples the writer has started to overwrite up to
        self._rec_tail = 0  # start of the oldest record still kept
        self._tail = 0  # oldest intact position: max(reserve - capacity, rec_tail)
        self._src_end: int | None = None  # source index one past the last written sample
        lock = threading.Lock()
        self._cond = threading.Condition(lock)  # readers wait on it for data
        self._room = threading.Condition(lock)  # a waiting writer, for readers to move on
        self._readers: list[RingReader] = []
        self.closed = False
        self.written = 0  # samples written (== _head)

    # --- writer --------------------------------------------------------------------------------
    def write(self, block: SampleBlock) -> None:
        """Append a block (the one writer only).  Missing channels are an error; extra ones are
        ignored.  A block longer than the ring is written in pieces (readers lose the front)."""
        if self.closed:
            raise ValueError("ring is closed")
        missing = [c for c in self.channels if c not in block.channels]
        if missing:
            raise ValueError(f"block lacks ring channel(s) {missing}; it has {sorted(block.channels)}")
        if block.fs_hz != self.fs_hz:
            raise ValueError(f"block sample rate {block.fs_hz} Hz differs from the ring's {self.fs_hz} Hz")
        n = block.n
        for k in range(0, n, self.capacity):
            m = min(self.capacity, n - k)
            first = k == 0
            self._write_piece(block, k, m, block.flags if first else block.flags & ~BlockFlags.GAP,
                              block.gap_samples if first else 0)

    def _write_piece(self, block: SampleBlock, k: int, m: int, flags: int, gap: int) -> None:
        first_index = block.first_index + k
        with self._cond:
            head = self._head
            last = self._nrec - 1
            slot = last % self.max_records
            extend = (last >= 0 and self._src_end == first_index and gap == 0
                      and int(self._rec_flags[slot]) == int(flags) and self._rec_meta[slot] == block.meta)
            if not extend:
                if self._nrec >= self.max_records:  # the oldest record (and its samples) go
                    self._rec_tail = int(self._rec_pos[(self._nrec + 1) % self.max_records])
                self._reserve = head + m
                self._tail = max(self._reserve - self.capacity, self._rec_tail, 0)
                s = self._nrec % self.max_records
                self._rec_pos[s], self._rec_first[s] = head, first_index
                self._rec_flags[s], self._rec_gap[s] = int(flags), int(gap)
                self._rec_meta[s] = dict(block.meta)
                self._nrec += 1
            else:
                self._reserve = head + m
                self._tail = max(self._reserve - self.capacity, self._rec_tail, 0)
            self._src_end = first_index + m
        # the copy runs without the lock: readers of older positions are not held up
        s0 = head % self.capacity
        s1 = min(s0 + m, self.capacity)
        for name, row in self._row.items():
            x = block.channels[name]
            self._data[row, s0:s1] = x[k:k + s1 - s0]
            if s1 - s0 < m:
                self._data[row, : m - (s1 - s0)] = x[k + s1 - s0:k + m]
        with self._cond:
            self._head = head + m
            self.written = self._head
            self._cond.notify_all()

    def close(self) -> None:
        """No more writes: readers drain what is left, then ``read`` returns None at once."""
        with self._cond:
            self.closed = True
            self._cond.notify_all()
            self._room.notify_all()

    def wait_for_room(self, n: int, timeout_s: float | None = None) -> bool:
        """Wait until ``n`` more samples (at most ``capacity``) can be written without lapping any
        reader, counting the views each still holds and the run records a new one would push out.
        False if ``timeout_s`` ran out or the ring was closed first (the writer then writes anyway
        or gives up: its choice)."""
        if not 0 < n <= self.capacity:
            raise ValueError(f"n must be in 1..{self.capacity} (the capacity), got {n}")
        deadline = Deadline(timeout_s)
        with self._cond:
            while True:
                if self.closed:
                    return False
                need = self._head + n - self.capacity  # the oldest position such a write keeps
                if self._nrec >= self.max_records:  # and a new run would drop the oldest record
                    need = max(need, int(self._rec_pos[(self._nrec + 1) % self.max_records]))
                if all(r._floor() >= need for r in self._readers):
                    return True
                if deadline.expired:
                    return False
                self._room.wait(deadline.left())

    # --- readers -------------------------------------------------------------------------------
    def reader(self, name: str = "", *, start: str = "oldest") -> RingReader:
        """A new reader at the oldest intact sample (``start='oldest'``) or at the head ('newest')."""
        if start not in ("oldest", "newest"):
            raise ValueError(f"start must be 'oldest' or 'newest', got {start!r}")
        with self._cond:
            pos = self._tail if start == "oldest" else self._head
            reader = RingReader(self, name, pos)
            self._readers.append(reader)
        return reader

    def remove_reader(self, reader: RingReader) -> None:
        """Forget ``reader`` (its stage ended while the ring goes on): a lossless writer no longer
        waits for it."""
        with self._cond:
            if reader in self._readers:
                self._readers.remove(reader)
            self._room.notify_all()

    @property
    def head(self) -> int:
        return self._head

    @property
    def tail(self) -> int:
        return self._tail

    def _record_at(self, pos: int, hint: int) -> int:
        """Index of the record holding position ``pos`` (caller holds the lock; pos in [tail, head))."""
        lo = max(hint, self._nrec - self.max_records, 0)
        if lo + 1 < self._nrec and self._rec_pos[(lo + 1) % self.max_records] <= pos:
            hi = self._nrec - 1  # binary search: the last record starting at or before pos
            while lo < hi:
                mid = (lo + hi + 1) // 2
                if self._rec_pos[mid % self.max_records] <= pos:
                    lo = mid
                else:
                    hi = mid - 1
        return lo


class RingReader:
    """One consumer's cursor.  ``lost_samples`` counts every sample it did not get intact."""

    def __init__(self, ring: RingBuffer, name: str, pos: int) -> None:
        self.ring, self.name = ring, name
        self.cursor = pos
        self.lost_samples = 0
        self.read_samples = 0
        self._rec_hint = 0
        self._pending_lost = 0  # lost since the last read handed out (reported with the next one)
        self._last_end: int | None = None  # source index one past the last block handed out
        self._held: int | None = None  # ring position of the views handed out and not released

    def _floor(self) -> int:
        """The oldest position this reader may still use (caller holds the ring's lock)."""
        return self.cursor if self._held is None else self._held

    @property
    def lag(self) -> int:
        """Samples written that this reader has not read yet."""
        return self.ring._head - self.cursor

    def wait(self, timeout_s: float | None = None) -> bool:
        """Wait until there is something to read (True), or ``timeout_s`` ran out or the ring is
        closed and drained (False); reads nothing."""
        ring = self.ring
        deadline = Deadline(timeout_s)
        with ring._cond:
            while ring._head <= self.cursor:
                if ring.closed or deadline.expired:
                    return False
                ring._cond.wait(deadline.left())
            return True

    def read(self, max_samples: int | None = None, timeout_s: float | None = 0.0, *,
             copy: bool = False) -> RingRead | None:
        """The next run of samples (at most ``max_samples``), waiting up to ``timeout_s`` (None:
        until data or close).  None if nothing came in time, or the ring is closed and drained.
        Samples lost before the run are in ``RingRead.lost`` (and ``lost_samples`` at once)."""
        if max_samples is not None and max_samples < 1:
            raise ValueError(f"max_samples must be >= 1, got {max_samples}")
        ring = self.ring
        deadline = Deadline(timeout_s)
        while True:
            with ring._cond:
                if self._held is not None:  # reading again: done with the last views
                    self._held = None
                    ring._room.notify_all()
                while True:
                    if ring._tail > self.cursor:  # lapped: the samples in between are gone
                        self._pending_lost += ring._tail - self.cursor
                        self.lost_samples += ring._tail - self.cursor
                        self.cursor = ring._tail
                    if ring._head > self.cursor:
                        break
                    if ring.closed or deadline.expired:
                        return None
                    ring._cond.wait(deadline.left())
                start, end, block = self._take(max_samples)
                if not copy:
                    self._held = start
            if copy:
                block = SampleBlock(block.first_index, block.fs_hz,
                                    {k: v.copy() for k, v in block.channels.items()},
                                    flags=block.flags, gap_samples=block.gap_samples, meta=block.meta)
                torn = min(ring._tail, end) - start
                if torn > 0:  # overwritten while being copied: drop those samples, keep the rest
                    self._pending_lost += torn
                    self.lost_samples += torn
                    if start + torn >= end:
                        continue
                    block = SampleBlock(block.first_index + torn, block.fs_hz,
                                        {k: v[torn:] for k, v in block.channels.items()},
                                        flags=block.flags & ~BlockFlags.GAP, meta=block.meta)
                    start += torn
            return self._finish(start, end, block)

    def _take(self, max_samples: int | None) -> tuple[int, int, SampleBlock]:
        """Views of the next run (caller holds the ring's lock); moves the cursor."""
        ring, pos = self.ring, self.cursor
        k = self._rec_hint = ring._record_at(pos, self._rec_hint)
        slot = k % ring.max_records
        rec_start = int(ring._rec_pos[slot])
        end = ring._head
        if k + 1 < ring._nrec:
            end = min(end, int(ring._rec_pos[(k + 1) % ring.max_records]))
        end = min(end, (pos // ring.capacity + 1) * ring.capacity)
        if max_samples is not None:
            end = min(end, pos + max_samples)
        s0 = pos % ring.capacity
        s1 = s0 + end - pos
        views = {}
        for name, row in ring._row.items():
            v = ring._data[row, s0:s1]
            v.flags.writeable = False
            views[name] = v
        first = int(ring._rec_first[slot]) + pos - rec_start
        flags = BlockFlags(int(ring._rec_flags[slot]))
        gap = int(ring._rec_gap[slot]) if pos == rec_start else 0
        if pos != rec_start:
            flags &= ~BlockFlags.GAP
        block = SampleBlock(first, ring.fs_hz, views, flags=flags, gap_samples=gap, meta=ring._rec_meta[slot])
        self.cursor = end
        return pos, end, block

    def _finish(self, start: int, end: int, block: SampleBlock) -> RingRead:
        lost, self._pending_lost = self._pending_lost, 0
        flags, gap = block.flags, block.gap_samples
        if self._last_end is not None and block.first_index != self._last_end:
            gap = block.first_index - self._last_end  # every index this reader misses, whatever the cause
            flags |= BlockFlags.GAP
        if lost:
            flags |= BlockFlags.OVERRUN
        if (flags, gap) != (block.flags, block.gap_samples):
            block = SampleBlock(block.first_index, block.fs_hz, block.channels, flags=flags,
                                gap_samples=gap, meta=block.meta)
        self._last_end = block.end_index
        self.read_samples += end - start
        return RingRead(block, lost, start, end)

    def valid(self, r: RingRead) -> bool:
        """Whether the writer has not (started to) overwrite the views of ``r`` yet."""
        return r.start >= self.ring._tail

    def release(self, r: RingRead) -> bool:
        """Done with the views of ``r``: True if they were intact throughout; if not, its samples
        are counted lost and whatever was computed from them must be dropped."""
        with self.ring._cond:  # judged before the views are let go: the writer waits on them
            ok = self.valid(r)
            if self._held is not None:
                self._held = None
                self.ring._room.notify_all()
        if not ok:
            self.lost_samples += r.n
            self.read_samples -= r.n
            self._last_end = None  # the next block's gap is not this reader's to compute
        return ok
