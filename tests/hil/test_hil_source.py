"""The pipeline's bench source turns the drivers' one acquisition loop (``Bench.read_aligned``,
issue 11), so a stream lost under a running pipeline is a bench fault like any other: the output
goes off first, the fault is recorded, and then it raises.  The source's own loop (before) let the
stream's error through with the generator still playing."""

import threading

import pytest

from hystbench.acquisition.sources import BenchSource
from hystbench.errors import InstrumentError

from .conftest import HANG_S, bench_file


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
