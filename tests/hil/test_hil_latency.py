"""Samples made before a change but sent after it (``BenchConfig.latency_s``).

The emulated rig makes a clock tick's samples at once, up to a tick ahead of real time, and the
instruments send them as a burst.  A change that lands between the making and the sending finds
the streams' readers caught up with their transports (on nothing new), so where they stand says
nothing about the burst still to come: it holds a whole tick of the bench as it was.  The moment is
made exact here: the clock is held, by a tap, between making a tick and sending it.
"""

import threading

from hystbench.blocks import SampleBlock

from .conftest import HANG_S

TICK = 20_000  # 200 ms at 100 kS/s: longer than every settling read of the shipped loops


def test_a_tick_made_before_a_change_and_sent_after_it_is_dropped(hil_factory):
    hil = hil_factory(**{"sim.block_samples": str(TICK)})
    bench, emu = hil.bench, hil.emu
    assert bench.latency_samples >= TICK  # a tick of samples can still be on its way
    bench.acquire(0.01, timeout_s=HANG_S)  # the streams run and the aligner has its cursor

    armed, made, release = threading.Event(), threading.Event(), threading.Event()
    held: list[int] = []

    def hold(block: SampleBlock) -> None:  # runs on the clock thread, after the rig, before the emulators
        if armed.is_set() and not held:
            held.append(block.first_index)
            made.set()
            release.wait(HANG_S)

    emu.taps.insert(0, hold)
    try:
        armed.set()
        assert made.wait(HANG_S), "the emulator's clock stopped"
        g = bench.generator.state
        bench.generator.set_sine(2 * g["frequency_hz"], g["amplitude_vpp"], g["offset_v"])
        changed_at = emu.changes[-1][0]  # the first sample the rig makes at the new frequency
        assert changed_at == held[0] + TICK  # the held tick was made before the change
        bench.discard_backlog()
    finally:
        release.set()  # the held tick goes out now, after discard_backlog returned
    runs = bench.acquire(0.01, timeout_s=HANG_S)
    assert runs[0].first_index >= changed_at, (
        f"samples {runs[0].first_index}..{changed_at} were made before the change and handed out after it")
