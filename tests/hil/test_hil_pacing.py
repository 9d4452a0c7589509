"""The emulated bench on a machine too busy for it (issue 16): its sample clock falls behind real
time and goes on from there, producing the same samples, so the drivers see no gap and no stall;
and an acquisition that cannot finish says why instead of "within the timeout".

The busy machine is made exact: a tap holds the clock thread (as a starved CPU would) until the
heartbeat has polled a few times, i.e. until real time has moved on without the clock."""

import threading

import pytest

from hystbench.errors import InstrumentTimeout

from .conftest import HANG_S, acquire_through
from .test_hil_faults import check_runs, streams_flowing


def hold_clock_ahead(hil, n_blocks):
    """Stop the clock thread when it reaches ``n_blocks`` blocks past where it is; returns (index,
    stalled, release).  The index is taken on the clock thread (``Hil.arm_ahead``): taken on the
    test's, a busy machine could let the clock pass it before the hold was set, and it never held."""
    stalled, release = threading.Event(), threading.Event()
    at: list[int] = []

    def tap(block):
        if at and block.first_index == at[0]:
            stalled.set()
            release.wait(HANG_S)

    hil.emu.taps.append(tap)
    hil.arm_ahead(n_blocks, at.append)
    return at[0], stalled, release


def let_real_time_pass(hil, polls):
    """Wait for ``polls`` heartbeat polls of the generator (one query each, every ``heartbeat_s``):
    real time passing, counted by events."""
    faults = hil.emu.generator.faults
    assert faults.wait_replies(faults.replies_sent + polls, HANG_S)


def test_a_clock_that_fell_behind_goes_on_with_the_same_samples(hil):
    """Held for longer than the shipped stall timeout (0.5 s): the ``hil`` fixtures take a held
    clock for what it is, not for a pulled cable (no reconnect, so no frame lost meanwhile)."""
    hil.bench.start_output()
    streams = streams_flowing(hil)
    at, stalled, release = hold_clock_ahead(hil, 2)
    assert stalled.wait(HANG_S)
    let_real_time_pass(hil, 7)  # polls 0.1 s apart: the clock is >= 0.6 s behind
    release.set()
    runs = acquire_through(hil, at + 20 * hil.emu.block_samples)
    assert check_runs(hil, runs) == 0 and len(runs) == 1  # every sample, each the rig's own
    assert hil.emu.pacer.slipped_s > 0  # it went on from where it was ...
    assert all(s.stats.frames_lost == s.stats.overruns == s.stats.reconnects == 0 for s in streams.values())


def test_an_acquisition_the_emulated_bench_cannot_feed_says_why(hil):
    hil.bench.start_output()
    streams_flowing(hil)
    end = hil.bench.acquire(0.01, timeout_s=HANG_S)[-1].end_index
    at, stalled, release = hold_clock_ahead(hil, 2)
    try:
        assert stalled.wait(HANG_S)
        fs = hil.config.fs_hz
        assert hil.bench.acquire((at - end) / fs, timeout_s=HANG_S)[-1].end_index == at  # all there is
        with pytest.raises(InstrumentTimeout, match=r"bench: only 0 of 10000 aligned samples within [\d.]+ s: the "
                                                    r"emulated bench produced no samples at all meanwhile: the "
                                                    r"machine is far too busy"):
            hil.bench.acquire(0.1, timeout_s=0.3)
    finally:
        release.set()
