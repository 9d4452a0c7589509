"""Learning through the drivers (``hystbench compensate --learn``: ``BenchActuation`` on the emulated
bench, issue 10's item 3): each iteration measures the table it just played, never samples left
over from before it, so no backlog can build up from one iteration to the next however long the
learning computes; and every sample between two measurements is accounted for (read, or passed
over on purpose by the first read after the new table, and counted).

The learning's computation is stood in for by waiting a fixed number of samples of the emulator's
clock, so the test is the same on an idle and on a busy machine."""

import numpy as np

from hystbench.compensator import BenchActuation

from .conftest import expected_wire

SETTLE, MEASURE = 5000, 10_000  # samples, as run_closed_loop reads them at 320 Hz (settle 50 ms)
COMPUTE = 20_000  # samples the clock runs on while the learning computes the next table (0.2 s)


def played_from(emu, uploads):
    """The first sample the rig made with the ``uploads``-th table and the output on."""
    return min(i for i, s in emu.changes if s["uploads"] == uploads and s["output"])


#: ``[bench] in_flight_s`` for this test: how late a sample made before a command may still arrive.  A
#: real instrument's buffer bounds it (the shipped 20 ms); the emulated instruments' sender threads
#: are bounded only by the machine, and a loaded one held them 80 ms once (the measurement then began
#: 3000 samples before the new table).  What is tested is the accounting, not that bound.
IN_FLIGHT_S = "0.3"


def test_each_iteration_measures_its_own_table_and_no_backlog_builds_up(hil_factory):
    hil = hil_factory(**{"bench.in_flight_s": IN_FLIGHT_S})
    act = BenchActuation(hil.bench, current_limit_a=1.8)
    unit = np.sin(2 * np.pi * np.arange(256) / 256)
    last_end = None
    for k in range(12):
        before = hil.bench.discarded_samples
        act.set_waveform(0.7 * (1 - 0.02 * k) * unit, 320.0)
        settle = act.read(SETTLE)  # the read after a new table passes over the old one's samples
        dropped = hil.bench.discarded_samples - before
        meas = act.read(MEASURE)
        assert hil.bench.discarded_samples - before == dropped, k  # only the first read after the table
        assert meas.first_index == settle.end_index, k  # consecutive reads are consecutive samples
        if last_end is not None:  # what the new table dropped is exactly what lies between
            assert settle.first_index == last_end + dropped, (k, last_end, dropped, settle.first_index)
        assert meas.first_index >= played_from(hil.emu, k + 1), k  # only samples of this table
        np.testing.assert_array_equal(meas.channels["current_A"],
                                      expected_wire(hil, "current_A", meas.first_index, meas.n))
        last_end = meas.end_index
        hil.wait_clock(hil.emu.next_index + COMPUTE)
