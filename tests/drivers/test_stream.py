"""Sample streams and alignment: exact gap accounting whatever the frames do (loss, duplicates,
overlap), reconnection with back-off and its limit, and alignment of several streams by index."""

import threading

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hystbench.blocks import BlockFlags, SampleBlock
from hystbench.drivers.align import StreamAligner
from hystbench.drivers.base import Backoff
from hystbench.drivers.protocols.framing import DeframerStats, Frame
from hystbench.drivers.stream import FrameSource, SampleStream
from hystbench.errors import ConnectionLost


class FakeSource(FrameSource):
    """Hands out scripted batches of frames; ``fail_opens`` reopen attempts fail."""

    def __init__(self, batches, fail_opens=0):
        self.batches = list(batches)
        self.fail_opens = fail_opens
        self.opens = 0
        self.deframer_stats = DeframerStats()
        self.lock = threading.Lock()

    def open(self):
        self.opens += 1
        if self.opens > 1 and self.fail_opens > 0:
            self.fail_opens -= 1
            raise ConnectionError("refused")

    def close(self):
        pass

    def read_frames(self, timeout_s):
        with self.lock:
            if self.batches:
                batch = self.batches.pop(0)
                if isinstance(batch, Exception):
                    raise batch
                return batch
        threading.Event().wait(min(timeout_s, 0.01))
        return []


HANG_S = 60.0  # a read's safety timeout: data or the error comes at once, only a hang takes this long


def frame(first, n, seq, value=None):
    data = (np.arange(first, first + n, dtype=np.float32) if value is None else np.full(n, value, np.float32))
    return Frame(7, seq, first, data[None, :])


def drain(stream, want):
    out = []
    while sum(b.n for b in out) < want:
        b = stream.read(HANG_S)
        assert b is not None, "stream stopped delivering"
        out.append(b)
    return out


def test_gaps_are_exact_and_duplicates_overlaps_are_dropped():
    batches = [[frame(0, 10, 0), frame(10, 10, 1)],
               [frame(35, 10, 4)],  # frames 2, 3 lost: 15 samples
               [frame(35, 10, 4), frame(40, 10, 5)],  # a duplicate, then one that overlaps by 5
               [frame(50, 10, 6)]]
    with SampleStream("s", FakeSource(batches), ["x"], 1000.0, stall_timeout_s=5.0) as s:
        blocks = drain(s, 45)
    x = np.concatenate([b.channels["x"] for b in blocks])
    idx = np.concatenate([b.first_index + np.arange(b.n) for b in blocks])
    np.testing.assert_array_equal(x, idx)  # every sample is the one at its index
    assert [b.gap_samples for b in blocks if b.flags & BlockFlags.GAP] == [15]
    assert s.stats.gap_samples == 15 and s.stats.frames_lost == 2 and s.stats.stale_frames == 1


@settings(max_examples=60, deadline=None)
@given(st.lists(st.booleans(), min_size=2, max_size=40), st.integers(1, 20))
def test_any_pattern_of_lost_frames_is_counted_exactly(kept, n):
    frames = [frame(i * n, n, i) for i, keep in enumerate(kept) if keep]
    if not frames:
        return
    with SampleStream("s", FakeSource([frames]), ["x"], 1000.0, stall_timeout_s=5.0) as s:
        blocks = drain(s, len(frames) * n)
    span = blocks[-1].end_index - blocks[0].first_index
    assert sum(b.n for b in blocks) + sum(b.gap_samples for b in blocks) == span
    lost_inside = kept.index(True), len(kept) - 1 - kept[::-1].index(True)
    assert s.stats.gap_samples == n * kept[lost_inside[0]:lost_inside[1] + 1].count(False)


def test_scale_and_skew_are_applied_and_recorded():
    with SampleStream("s", FakeSource([[frame(0, 4, 0, value=2.0)]]), ["force_N"], 1000.0,
                      scale={"force_N": 50.0}, skew_s=3e-6, stall_timeout_s=5.0) as s:
        b = s.read(HANG_S)
    np.testing.assert_array_equal(b.channels["force_N"], 100.0)
    assert b.meta == {"skew_s.force_N": 3e-6}


def test_lost_transport_is_reconnected_with_backoff():
    src = FakeSource([[frame(0, 10, 0)], ConnectionError("peer closed"), [frame(30, 10, 3)]], fail_opens=2)
    with SampleStream("s", src, ["x"], 1000.0, backoff=Backoff(0.001, 2.0, 0.01, 5), stall_timeout_s=5.0) as s:
        blocks = drain(s, 20)
    assert s.stats.reconnects == 1 and src.opens == 4 and blocks[1].gap_samples == 20


def test_reconnection_gives_up_with_connection_lost():
    src = FakeSource([[frame(0, 10, 0)], ConnectionError("peer closed")], fail_opens=99)
    with SampleStream("gen", src, ["x"], 1000.0, backoff=Backoff(0.001, 2.0, 0.01, 3), stall_timeout_s=5.0) as s:
        assert s.read(HANG_S).n == 10
        with pytest.raises(ConnectionLost, match="gen: sample stream lost .transport lost: peer closed.; "
                                                 "3 reconnection attempts failed"):
            s.read(HANG_S)


def test_an_instrument_that_connects_and_sends_nothing_is_given_up():
    """Every reopen of a silent instrument succeeded (it takes the TCP connection), so the stream
    retried for ever and the daemon said "running" with no sample; once it has been silent for
    ``lost_after_s``, read raises ConnectionLost saying so (a fault the service sees)."""
    src = FakeSource([[frame(0, 10, 0)]])
    with SampleStream("amp", src, ["x"], 1000.0, stall_timeout_s=0.02, backoff=Backoff(0.001, 2.0, 0.01, 3),
                      lost_after_s=0.2) as s:
        assert s.read(HANG_S).n == 10
        with pytest.raises(ConnectionLost, match=r"amp: sample stream lost .no frame for 0.2 s through \d+ "
                                                 "reconnections: the instrument takes the connection and sends no "
                                                 "samples"):
            while True:
                assert s.read(HANG_S) is not None
    assert s.stats.reconnects >= 1  # it was reopened meanwhile, each time with success


def test_a_stream_silent_through_more_reopens_than_the_attempts_comes_back():
    """A starved machine held the emulated TCP streams silent through six 0.7 s reconnections and
    they came back (CI, 2026-11-30); counted in reopens, that silence was a lost stream.  Within
    ``lost_after_s``, however many reopens it takes, the samples go on, with the exact gap."""
    attempts = 3
    src = FakeSource([[frame(0, 10, 0)]])
    opened = src.open

    def open_() -> None:  # frames again at the attempts + 2nd reopen, not before
        opened()
        if src.opens == attempts + 3:
            with src.lock:
                src.batches.append([frame(50, 10, 5)])

    src.open = open_
    with SampleStream("gen", src, ["x"], 1000.0, stall_timeout_s=0.02, backoff=Backoff(0.001, 2.0, 0.01, attempts),
                      lost_after_s=HANG_S) as s:
        assert s.read(HANG_S).n == 10
        back = s.read(HANG_S)
    assert back.first_index == 50 and back.gap_samples == 40 and back.flags & BlockFlags.GAP
    assert s.stats.reconnects >= attempts + 2  # more reopens than the attempts, and not lost


def test_silence_counts_as_a_stall_and_reopens():
    src = FakeSource([[frame(0, 10, 0)]])
    with SampleStream("s", src, ["x"], 1000.0, stall_timeout_s=0.05, backoff=Backoff(0.001, 2, 0.01, 3)) as s:
        assert s.read(HANG_S).n == 10
        reopened = threading.Event()
        src.open = lambda: (FakeSource.open(src), reopened.set())  # the reopen is the event waited on
        assert reopened.wait(HANG_S)
    assert s.stats.stalls >= 1 and s.stats.reconnects >= 1


def block(first, n, ch, value=None):
    x = np.arange(first, first + n, dtype=float) if value is None else np.full(n, value)
    return SampleBlock(first, 100.0, {ch: x})


def test_aligner_starts_where_all_streams_have_begun_and_counts_gaps_exactly():
    al = StreamAligner(["a", "b"])
    al.push("a", block(0, 50, "x"))
    assert al.pop() is None  # b has nothing yet
    al.push("b", block(20, 20, "y"))
    al.push("b", block(45, 30, "y"))  # b lost 40..44
    al.push("a", block(50, 50, "x"))
    out = []
    while (b := al.pop()) is not None:
        out.append(b)
    assert [(b.first_index, b.n, b.gap_samples) for b in out] == [(20, 20, 0), (45, 5, 5), (50, 25, 0)]
    for b in out:
        np.testing.assert_array_equal(b.channels["x"], b.channels["y"])  # same index, same sample
    assert al.start_index == 20 and al.gap_samples == 5


@settings(max_examples=60, deadline=None)
@given(st.lists(st.tuples(st.integers(0, 2), st.integers(1, 30), st.integers(0, 5)), min_size=1, max_size=30))
def test_aligner_never_invents_or_moves_a_sample(pieces):
    """Three streams with arbitrary cuts and holes: output samples are at their own index in every
    channel, and output + gaps covers the span."""
    al = StreamAligner(["s0", "s1", "s2"])
    pos = [0, 3, 7]
    for which, n, hole in pieces:
        al.push(f"s{which}", block(pos[which] + hole, n, f"c{which}"))
        pos[which] += hole + n
    out = []
    while (b := al.pop(max_samples=17)) is not None:
        out.append(b)
    for b in out:
        for x in b.channels.values():
            np.testing.assert_array_equal(x, b.first_index + np.arange(b.n))
    if out:
        assert sum(b.n for b in out) + sum(b.gap_samples for b in out) == out[-1].end_index - al.start_index
