"""The pipeline's bench source turns the drivers' one acquisition loop (``Bench.read_aligned``,
issue 11), so a stream lost under a running pipeline is a bench fault like any other: the output
goes off first, the fault is recorded, and then it raises.  The source's own loop (before) let the
stream's error through with the generator still playing."""

import threading

import numpy as np
import pytest

from hystbench.acquisition.sources import BenchSource
from hystbench.errors import InstrumentError

from .conftest import HANG_S, Truth, bench_file


def test_a_stream_lost_under_the_source_switches_the_output_off_before_it_raises(tmp_path):
    src = BenchSource(str(bench_file(tmp_path)))
    stop = threading.Event()
    safety = threading.Timer(HANG_S, stop.set)  # only a hang takes this long: blocks() then just ends
    try:
        src.set_output(True)
        blocks = src.blocks(stop)
        on = next(b for b in blocks if b.meta["output_on"])
        assert src.emu.generator.state["output"] and not src.bench.faults
        src.bench.pause_heartbeat()  # the heartbeat would notice too: here only the acquisition loop may
        src.emu.integrator.disconnect()  # bus-off: the flux stream stops for good
        safety.start()
        with pytest.raises(InstrumentError, match="flux_integrator: sample stream lost"):
            for b in blocks:
                assert b.first_index >= on.end_index
        assert not stop.is_set(), "the lost stream was never noticed"
        fault = src.bench.faults[0]
        assert fault.instrument == "flux_integrator" and fault.output_off
        assert not src.emu.generator.state["output"]  # switched off by the bench, before the error left it
    finally:
        safety.cancel()
        src.close()


def test_a_command_given_while_the_reading_is_behind_settles_from_where_the_instruments_clock_was(tmp_path):
    """The reading one second behind the instruments (a starved thread, a backlog in the sockets):
    the switch-on takes effect where the instruments' clock stands, a second past the reading's
    cursor.  No sample from before it is handed on as settled (the cursor plus the 0.1 s settling
    once was: a second of output-off samples labelled output on, which the estimator then fitted)."""
    src = BenchSource(str(bench_file(tmp_path)), excitation=(320.0, 1.0))
    truth, ahead, stop = Truth(), threading.Event(), threading.Event()
    safety = threading.Timer(HANG_S, stop.set)  # only a hang takes this long: blocks() then just ends
    try:
        blocks = src.blocks(stop)
        first = next(blocks)
        behind = first.end_index + int(src.fs_hz)  # a second of samples made and not yet read
        src.emu.taps += [truth, lambda b: b.end_index >= behind and ahead.set()]
        assert ahead.wait(HANG_S)
        src.set_output(True)
        safety.start()
        settled: list = []
        for b in blocks:
            if not b.meta.get("settling"):
                settled.append(b)
            if sum(s.n for s in settled) >= 0.2 * src.fs_hz:
                break
        assert not stop.is_set(), "settling never ended"
        current = np.concatenate([t.channels["current_A"] for t in truth.blocks])
        switched_on = truth.blocks[0].first_index + int(np.argmax(np.abs(current) > 0.25))
        assert switched_on >= behind  # where the clock was, not where the reading was
        assert settled[0].first_index >= switched_on
        assert all(b.meta["output_on"] for b in settled)
        periods = np.concatenate([b.channels["current_A"] for b in settled])
        per = int(src.fs_hz / 320.0)
        ptp = np.ptp(periods[: periods.size // per * per].reshape(-1, per), axis=1)
        assert ptp.min() > 0.9  # every settled period is the 1 A-pp sine, none the idle output
    finally:
        safety.cancel()
        src.close()
