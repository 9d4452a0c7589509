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
        bench.commanded()
        change = bench.wait_change(HANG_S)  # the readers caught up, on nothing new: the tick is still held
    finally:
        release.set()  # the held tick goes out now, after the change's index was known
    assert change >= changed_at, f"the change placed at {change}, before the held tick's end {changed_at}"
    runs = bench.acquire(0.01, timeout_s=HANG_S, since_command=True)
    assert runs[0].first_index >= changed_at, (
        f"samples {runs[0].first_index}..{changed_at} were made before the change and handed out after it")


def test_the_change_index_is_known_once_read_and_acquire_since_command_starts_there(hil):
    """The one way a bench's users learn where a command takes effect: nothing before a command;
    after one, the first live sample plus what was on its way (learned without dropping anything),
    kept until the next command; ``acquire(since_command=True)`` starts exactly there, once."""
    bench = hil.bench
    bench.acquire(0.01, timeout_s=HANG_S)  # the streams run and the aligner has its cursor
    assert bench.change_index() is None and bench.wait_change() is None  # no command yet
    g = bench.generator.state
    bench.generator.set_sine(2 * g["frequency_hz"], g["amplitude_vpp"], g["offset_v"])
    bench.commanded()
    cursor, dropped = bench.next_index, bench.discarded_samples
    change = bench.wait_change(HANG_S)
    assert change >= cursor + bench.latency_samples and bench.change_index() == change  # kept
    assert bench.next_index == cursor and bench.discarded_samples == dropped  # learning it handed out and dropped nothing
    first = bench.acquire(0.01, timeout_s=HANG_S, since_command=True)
    assert first[0].first_index == change and bench.discarded_samples - dropped == change - cursor
    again = bench.acquire(0.01, timeout_s=HANG_S, since_command=True)  # the same command: nothing more passed over
    assert again[0].first_index == first[-1].end_index and bench.discarded_samples - dropped == change - cursor
