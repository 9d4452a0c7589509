"""The ring buffer's invariants, against a model (hypothesis) and under real threads.

Every sample carries its own source index (channel a = index, channel b = -index), so a stale or
torn sample is seen at once; every reader must account for every sample exactly once, as read or
as lost.
"""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hystbench.acquisition.ring import RingBuffer
from hystbench.blocks import BlockFlags, SampleBlock

FS = 1000.0
HANG_S = 60.0  # a safety timeout: what is waited for comes at once, only a hang takes this long


def block(first: int, n: int, *, gap: int = 0, clip: bool = False, seg: int = 0) -> SampleBlock:
    idx = np.arange(first, first + n, dtype=np.float64)
    flags = (BlockFlags.GAP if gap else BlockFlags.NONE) | (BlockFlags.CLIP if clip else BlockFlags.NONE)
    return SampleBlock(first, FS, {"a": idx, "b": -idx, "extra": idx}, flags=flags, gap_samples=gap,
                       meta={"seg": float(seg)})


def check_block(b: SampleBlock) -> None:
    """Never stale, never torn: the values are exactly the block's own indices."""
    want = np.arange(b.first_index, b.end_index, dtype=np.float64)
    np.testing.assert_array_equal(b.channels["a"], want)
    np.testing.assert_array_equal(b.channels["b"], -want)


write_op = st.tuples(st.just("w"), st.integers(1, 40), st.sampled_from([0, 0, 0, 1, 7]), st.booleans(),
                     st.integers(0, 2))
read_op = st.tuples(st.just("r"), st.integers(0, 2), st.one_of(st.none(), st.integers(1, 30)), st.booleans())


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(capacity=st.integers(1, 64), max_records=st.integers(2, 6),
       ops=st.lists(st.one_of(write_op, read_op), max_size=60))
def test_ring_against_model(capacity: int, max_records: int, ops: list) -> None:
    ring = RingBuffer(["a", "b"], capacity, fs_hz=FS, dtype=np.float64, max_records=max_records)
    readers = [ring.reader(f"r{i}") for i in range(3)]
    start = [r.cursor for r in readers]
    src_meta: dict[int, float] = {}  # source index -> segment, to check meta never straddles
    src_clip: dict[int, bool] = {}
    src_gaps: list[tuple[int, int]] = []
    nxt = 0
    delivered: list[list] = [[], [], []]
    for op in ops:
        if op[0] == "w":
            _, n, gap, clip, seg = op
            first = nxt + gap
            if gap:
                src_gaps.append((first, gap))
            ring.write(block(first, n, gap=gap, clip=clip, seg=seg))
            for i in range(first, first + n):
                src_meta[i], src_clip[i] = float(seg), clip
            nxt = first + n
        else:
            _, k, max_samples, copy = op
            r = readers[k]
            before, head = r.cursor, ring.head
            got = r.read(max_samples, timeout_s=0.0, copy=copy)
            if got is None:
                assert before == head
                continue
            b = got.block
            check_block(b)
            assert r.release(got)  # nothing writes in between, so views are intact
            assert got.start == before + got.lost  # the loss is exactly the positions skipped
            assert got.lost == max(0, ring.tail - before) or got.lost == 0
            assert ring.tail <= got.start and got.end <= ring.head
            assert 1 <= b.n <= (max_samples or capacity) and b.n <= capacity
            assert {src_meta[i] for i in range(b.first_index, b.end_index)} == {b.meta["seg"]}
            assert {src_clip[i] for i in range(b.first_index, b.end_index)} == {bool(b.flags & BlockFlags.CLIP)}
            assert bool(b.flags & BlockFlags.OVERRUN) == (got.lost > 0)
            delivered[k].append(got)
    for k, r in enumerate(readers):  # drain: read + lost accounts for every sample written
        while (got := r.read(timeout_s=0.0)) is not None:
            check_block(got.block)
            delivered[k].append(got)
        assert r.read_samples + r.lost_samples == ring.head - start[k]
        assert sum(g.n for g in delivered[k]) == r.read_samples
        assert sum(g.lost for g in delivered[k]) == r.lost_samples
        # gaps: each block after the first says exactly how many source indices it skipped
        for prev, cur in zip(delivered[k], delivered[k][1:]):
            skipped = cur.block.first_index - prev.block.end_index
            assert cur.block.gap_samples == skipped
            assert bool(cur.block.flags & BlockFlags.GAP) == (skipped > 0)
        if r.lost_samples == 0:  # a reader that lost nothing sees every source gap, exactly
            seen = {(g.block.first_index, g.block.gap_samples) for g in delivered[k] if g.block.flags & BlockFlags.GAP}
            first_seen = delivered[k][0].block.first_index if delivered[k] else nxt
            assert seen == {(i, g) for i, g in src_gaps if i >= first_seen}


@settings(max_examples=150, deadline=None)
@given(capacity=st.integers(1, 50), sizes=st.lists(st.integers(1, 120), min_size=1, max_size=30),
       every=st.integers(1, 4))
def test_loss_only_when_lapped(capacity: int, sizes: list[int], every: int) -> None:
    """With records to spare, a reader loses exactly what it was lapped by, nothing more."""
    ring = RingBuffer(["a", "b"], capacity, fs_hz=FS, dtype=np.float64, max_records=1000)
    r = ring.reader()
    nxt = 0
    for i, n in enumerate(sizes):
        ring.write(block(nxt, n))
        nxt += n
        if i % every == 0:
            want_lost = max(0, ring.head - capacity - r.cursor)
            got = r.read(timeout_s=0.0)
            assert got is not None and got.lost == want_lost
            check_block(got.block)
    want_lost = max(0, ring.head - capacity - r.cursor)
    while (got := r.read(timeout_s=0.0)) is not None:
        assert got.lost == want_lost
        want_lost = 0
        check_block(got.block)
    assert r.read_samples + r.lost_samples == nxt


def test_views_are_zero_copy_read_only_and_torn_views_are_reported() -> None:
    ring = RingBuffer(["a", "b"], 10, fs_hz=FS, dtype=np.float64)
    r = ring.reader()
    ring.write(block(0, 6))
    got = r.read()
    a = got.block.channels["a"]
    assert np.shares_memory(a, ring._data)
    with pytest.raises(ValueError):
        a[0] = 1.0
    assert r.valid(got)
    ring.write(block(6, 5))  # overwrites position 0 (the ring holds 10)
    assert not r.valid(got)
    assert not r.release(got)
    assert r.lost_samples == 6 and r.read_samples == 0
    nxt = r.read()
    assert nxt.block.first_index == 6 and nxt.lost == 0 and nxt.n == 4  # a read stops at the wrap
    assert r.read().block.first_index == 10
    assert r.read_samples + r.lost_samples == 11


def test_newest_reader_oversized_block_close_and_bad_input() -> None:
    ring = RingBuffer(["a", "b"], 8, fs_hz=FS, dtype=np.float64)
    old, _ = ring.reader(), None
    ring.write(block(0, 20))  # longer than the ring: written in pieces, the front is lost
    new = ring.reader(start="newest")
    assert new.read(timeout_s=0.0) is None
    got = old.read(timeout_s=0.0)
    assert got.lost == 12 and got.block.first_index == 12
    check_block(got.block)
    ring.close()
    t0 = time.monotonic()
    assert new.read(timeout_s=HANG_S) is None and time.monotonic() - t0 < HANG_S / 2  # close wakes it
    with pytest.raises(ValueError, match="closed"):
        ring.write(block(20, 1))
    ring2 = RingBuffer(["a", "b"], 8, fs_hz=FS)
    with pytest.raises(ValueError, match=r"lacks ring channel"):
        ring2.write(SampleBlock(0, FS, {"a": np.zeros(3)}))
    with pytest.raises(ValueError, match="sample rate"):
        ring2.write(SampleBlock(0, 2 * FS, {"a": np.zeros(3), "b": np.zeros(3)}))
    with pytest.raises(ValueError, match="distinct"):
        RingBuffer(["a", "a"], 8, fs_hz=FS)


def test_read_waits_with_timeout_and_wakes_on_write() -> None:
    ring = RingBuffer(["a", "b"], 100, fs_hz=FS, dtype=np.float64)
    r = ring.reader()
    t0 = time.monotonic()
    assert r.read(timeout_s=0.05) is None
    assert time.monotonic() - t0 > 0.04  # it waited its timeout (a busy machine only makes this longer)
    threading.Timer(0.05, lambda: ring.write(block(0, 5))).start()
    got = r.read(timeout_s=HANG_S)  # woken by the write
    assert got is not None and got.n == 5


def test_one_writer_many_threaded_readers() -> None:
    """Real threads: a fast writer, a copying reader, a zero-copy reader that releases, a slow
    one.  No reader ever sees a wrong sample, and each accounts for every sample."""
    ring = RingBuffer(["a", "b"], 4096, fs_hz=FS, dtype=np.float64, max_records=64)
    readers = [ring.reader(n) for n in ("copy", "view", "slow")]
    errors: list[str] = []
    stop = threading.Event()

    def consume(r, copy: bool, pause: float) -> None:
        while True:
            got = r.read(700, timeout_s=0.2, copy=copy)
            if got is None:
                if ring.closed and r.lag == 0:
                    return
                continue
            a, b = got.block.channels["a"], got.block.channels["b"]
            want = np.arange(got.block.first_index, got.block.end_index, dtype=np.float64)
            good = np.array_equal(a, want) and np.array_equal(b, -want)
            if pause:
                time.sleep(pause)
            intact = copy or r.release(got)
            if intact and not good:
                errors.append(f"{r.name}: wrong samples at {got.block.first_index}")

    threads = [threading.Thread(target=consume, args=(r, c, p), daemon=True)
               for r, c, p in zip(readers, (True, False, False), (0.0, 0.0, 0.002))]
    for t in threads:
        t.start()
    rng = np.random.default_rng(1)
    nxt = 0
    # write until the slow reader has been lapped (the event this test needs), at least 200k samples
    while (nxt < 200_000 or readers[2].lost_samples == 0) and nxt < 200_000_000 and not stop.is_set():
        n = int(rng.integers(1, 900))
        ring.write(block(nxt, n, seg=nxt // 5000))
        nxt += n
    ring.close()
    for t in threads:
        t.join(timeout=5.0)
        assert not t.is_alive()
    assert not errors, errors[:3]
    for r in readers:
        assert r.read_samples + r.lost_samples == nxt, r.name
    assert readers[2].lost_samples > 0  # the slow reader was lapped and was told so


def test_a_release_is_judged_before_the_waiting_writer_may_reuse_the_views() -> None:
    """A lossless writer waits for room on the views a reader holds.  Releasing them must judge
    them intact first: judged after letting go, the woken writer could overwrite them in between
    and a complete read was counted lost (replay under load lost 300-1500 samples this way).  The
    check below stalls at the judging moment until the writer has written, or, when the writer is
    rightly still held back, for a short while: its outcome never depends on the machine's speed."""
    from hystbench.acquisition.ring import RingReader

    ring = RingBuffer(["a", "b"], 100, fs_hz=FS)
    reader = ring.reader("r")
    ring.write(block(0, 100))
    got = reader.read()  # holds the views of all 100 samples
    written = threading.Event()

    def writer() -> None:
        assert ring.wait_for_room(50, timeout_s=HANG_S)
        ring.write(block(100, 50))
        written.set()

    real_valid = RingReader.valid

    def valid_after_the_writer(self, r):
        written.wait(0.5)  # old order: the writer was woken already and writes now
        return real_valid(self, r)

    t = threading.Thread(target=writer, daemon=True)
    t.start()
    RingReader.valid = valid_after_the_writer
    try:
        assert reader.release(got)  # every one of the 100 samples was used intact
    finally:
        RingReader.valid = real_valid
    t.join(HANG_S)
    assert written.is_set() and reader.lost_samples == 0
