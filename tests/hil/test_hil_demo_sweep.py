"""``make demo``'s sweeps through the drivers (issue 16): each point's settling starts at the
frequency change, however long the change took, so no recording holds samples of the last
frequency.  On a busy machine the SCPI round trips of a change took longer than the samples the
settling read skipped, and the 480 Hz recording began with 20 ms of 320 Hz.

The slow machine is made exact: each change reaches the generator only once the emulator's clock
has run on twice the settling time since it was asked for.

What each recording must skip is the bench's own settling (``analysis.settling``: 10 time constants
of the measurement chain, 30 ms for ecore_pm), not the demo's whole ``SETTLE_S``: samples made before
the change are passed over up to where the streams' readers, caught up, placed the clock at the
change, plus what was on its way then (``Bench.change_index``, read from by
``Bench.acquire(..., since_command=True)``), and ``SETTLE_S`` leaves room for the ringing after it.
"""

from hystbench.analysis.settling import settling_time_s
from hystbench.reports import demo
from hystbench.drivers.bench import Bench
from hystbench.sim_backend.emulators.bench import EmulatedBench

from .conftest import wait_clock


def test_each_point_is_measured_after_its_change_and_the_settling(monkeypatch):
    made: list[EmulatedBench] = []
    measured: list[tuple[float, int]] = []  # (frequency, first sample of the recording)
    settle = int(demo.SETTLE_S * 100_000)

    class Emulated(EmulatedBench):
        def __init__(self, *a, **kw):
            super().__init__(*a, **kw)
            made.append(self)

    class SlowToChange(Bench):
        def open(self):
            super().open()
            set_sine = self.generator.set_sine

            def slow_set_sine(*args):
                wait_clock(made[-1], made[-1].next_index + 2 * settle)
                set_sine(*args)

            self.generator.set_sine = slow_set_sine
            return self

        def acquire(self, duration_s, **kw):
            runs = super().acquire(duration_s, **kw)
            if duration_s == demo.DURATION_S:
                measured.append((made[-1].rig.frequency_hz, runs[0].first_index))
            return runs

    monkeypatch.setattr(demo, "EmulatedBench", Emulated)
    monkeypatch.setattr(demo, "Bench", SlowToChange)
    monkeypatch.setattr(demo, "DURATION_S", 0.05)
    recs = demo._sweep_through_drivers("ecore_pm", 1.4, (320.0, 480.0), lambda: None)
    assert [r.frequency_hz for r in recs] == [320.0, 480.0] and len(measured) == 2
    ringing = settling_time_s(made[-1].rig.metadata()) * 100_000
    assert 0 < ringing < settle  # the demo's settling read has room for samples in flight
    for f, first in measured:
        changed = max(i for i, s in made[-1].changes if s["frequency_hz"] == f and s["output"])
        assert first >= changed + ringing, (f, first, changed, ringing)
