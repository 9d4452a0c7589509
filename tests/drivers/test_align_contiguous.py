"""``StreamAligner.contiguous``: how far the next pops reach without a gap, and whether a break ends
that run.  The acquisition loop gathers blocks up to a minimum size with it (issue 14), so it must
never count a sample across a hole in any stream, nor call a run ended that can still grow."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hystbench.blocks import SampleBlock
from hystbench.drivers.align import StreamAligner


def block(first, n, ch):
    return SampleBlock(first, 100.0, {ch: np.arange(first, first + n, dtype=float)})


def test_nothing_is_counted_before_the_first_pop():
    al = StreamAligner(["a", "b"])
    al.push("a", block(0, 50, "x"))
    al.push("b", block(0, 50, "y"))
    assert al.contiguous() == (0, False)


def test_the_run_is_the_shortest_stream_and_a_hole_in_it_ends_the_run():
    al = StreamAligner(["a", "b"])
    al.push("a", block(0, 10, "x"))
    al.push("a", block(10, 30, "x"))  # a: 0..40 in two pieces, no hole
    al.push("b", block(0, 10, "y"))
    al.push("b", block(10, 15, "y"))
    al.push("b", block(30, 20, "y"))  # b: 0..25, then a hole 25..30
    assert al.pop().n == 10  # the cursor is at 10
    assert al.contiguous() == (15, True)  # 10..25: b's hole ends it
    al2 = StreamAligner(["a", "b"])
    al2.push("a", block(0, 10, "x"))
    al2.push("a", block(10, 30, "x"))
    al2.push("b", block(0, 10, "y"))
    al2.push("b", block(10, 40, "y"))  # b reaches further, a's end is only where its data stops
    al2.pop()
    assert al2.contiguous() == (30, False)  # 10..40, more of a may come


def test_a_hole_in_a_stream_that_does_not_limit_the_run_does_not_end_it():
    al = StreamAligner(["a", "b"])
    al.push("a", block(0, 20, "x"))  # a ends at 20 (limits)
    al.push("b", block(0, 30, "y"))
    al.push("b", block(40, 10, "y"))  # b's hole at 30 is past a's end
    al.pop(5)
    assert al.contiguous() == (15, False)


def three_streams(pieces: list[tuple[int, int, int]]) -> StreamAligner:
    """An aligner fed ``pieces`` (stream, samples, hole): streams start at 0, 2 and 5, and a piece
    with hole 3 starts 3 samples after the last one ended (the other values: no hole)."""
    al = StreamAligner(["s0", "s1", "s2"])
    pos = [0, 2, 5]
    for which, n, hole in pieces:
        al.push(f"s{which}", block(pos[which] + (hole if hole == 3 else 0), n, f"c{which}"))
        pos[which] += (hole if hole == 3 else 0) + n
    return al


@settings(max_examples=80, deadline=None)
@given(st.lists(st.tuples(st.integers(0, 2), st.integers(1, 30), st.integers(0, 3)), min_size=3, max_size=30),
       st.integers(1, 20))
def test_the_counted_run_pops_without_a_gap(pieces, first_pop):
    """Three streams with arbitrary cuts and holes: the n that ``contiguous`` counts come out of
    the next pops as one gap-free run at the cursor (an independent check: the pops themselves)."""
    al = three_streams(pieces)
    if al.pop(first_pop) is None:
        return
    n, ended = al.contiguous()
    cursor = al.cursor
    got = 0
    while got < n:
        b = al.pop(n - got)
        assert b is not None and b.first_index == cursor + got and b.gap_samples == 0
        got += b.n
    assert got == n
    nxt = al.pop()
    if ended:  # a hole follows: the next block (once every stream has data) starts after a gap
        assert nxt is None or nxt.gap_samples > 0
    else:  # the limiting stream's samples end there: nothing more until it sends more
        assert nxt is None


@settings(max_examples=80, deadline=None)
@given(st.lists(st.tuples(st.integers(0, 2), st.integers(1, 30), st.integers(0, 3)), min_size=3, max_size=30),
       st.integers(1, 20))
def test_take_hands_out_the_counted_run_in_one_block_every_sample_at_its_index(pieces, first_pop):
    al = three_streams(pieces)
    if al.pop(first_pop) is None:
        return
    n, _ = al.contiguous()
    if n == 0:
        return
    cursor = al.cursor
    b = al.take(n)
    assert (b.first_index, b.n, b.gap_samples) == (cursor, n, 0) and al.cursor == cursor + n
    for x in b.channels.values():  # the samples are their own index in every stream
        np.testing.assert_array_equal(x, cursor + np.arange(n))
    assert al.contiguous()[0] == 0  # the run is used up


def test_take_refuses_to_reach_across_a_hole():
    al = StreamAligner(["a", "b"])
    al.push("a", block(0, 40, "x"))
    al.push("b", block(0, 10, "y"))
    al.push("b", block(20, 20, "y"))  # b lost 10..20
    al.pop(5)
    with pytest.raises(ValueError, match="b does not hold samples 10..15"):
        al.take(10)
