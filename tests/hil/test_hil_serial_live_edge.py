"""A serial stream's live edge against the emulated bench's clock (the demo sweep's race).

``Bench.change_index`` places a command's first sample where a stream's reader, having emptied
its line after the command, left the stream, plus one clock tick (``latency_samples``: a tick's
samples are made at once and may still be on their way).  A pseudo-terminal holds less than a
tick's burst, so the rest of the emulated charge amplifier's frames waited in the emulator, where
no reader sees them, and for as long as it liked: 1 MB of them.  A reader that emptied the line
then placed the command up to seconds early, and the demo's first recording began 1500 samples
before the output came on (``test_hil_demo_sweep``, 1 run in 7; the streams open after that
command, and the force stream's line had been filling since the emulator started).

Here the test makes the clock's ticks itself (the emulated bench is not started) and waits on the
reader's own reads, so what each test checks happens on every run.  What the pseudo-terminal itself
holds (about 12 kB: up to 2500 samples of the force stream's frames) is on the line, like a real
port's buffers: the drivers' ``in_flight_s``.
"""

from __future__ import annotations

import contextlib
import math
import threading
import time
from typing import Iterator

from hystbench.drivers.protocols.bench_config import load_bench_config
from hystbench.drivers.stream import SampleStream, frame_source
from hystbench.sim_backend.emulators.bench import EmulatedBench
from hystbench.sim_backend.emulators.charge_amplifier import CHARGE_AMP_STREAM_ID

from .conftest import HANG_S, bench_file


class Reads:
    """The stream's reader, watched: every read it begins is announced, and it begins one only
    after noting where the last one left the stream (``SampleStream._reader``)."""

    def __init__(self, stream: SampleStream) -> None:
        self.stream, self.began = stream, threading.Condition()
        self.running = threading.Event()  # cleared: the reader gets no CPU (it waits before its next read)
        self.running.set()
        read_frames = stream.source.read_frames

        def announced(timeout_s: float):
            assert self.running.wait(HANG_S)
            with self.began:
                self.began.notify_all()
            return read_frames(timeout_s)

        stream.source.read_frames = announced  # type: ignore[method-assign]

    def live_after(self, t: float) -> int:
        """``live_index_after(t)``, once a read that began after ``t`` has emptied the line."""
        with self.began:
            assert self.began.wait_for(lambda: self.stream.live_index_after(t) is not None, HANG_S), \
                "the reader never emptied the line"
        return self.stream.live_index_after(t)


@contextlib.contextmanager
def clock_by_hand(tmp_path) -> Iterator[tuple[EmulatedBench, int]]:
    """The shipped bench, emulated, its clock not started; and the drivers' ``latency_samples``."""
    config = load_bench_config(bench_file(tmp_path))
    with contextlib.closing(EmulatedBench(config)) as emu:
        yield emu, math.ceil(config.latency_s * config.fs_hz - 1e-9)


@contextlib.contextmanager
def force_stream(emu: EmulatedBench) -> Iterator[Reads]:
    """The charge amplifier's stream opened as its driver opens it (the first open of the port
    drops what the line held)."""
    source = frame_source(emu.addresses["charge_amplifier"]["stream_serial"], CHARGE_AMP_STREAM_ID)
    stream = SampleStream("charge_amplifier", source, ["force_N"], emu.fs_hz, stall_timeout_s=HANG_S)
    reads = Reads(stream)
    with stream:
        yield reads


def test_a_serial_stream_opened_late_holds_nothing_older_than_a_tick(tmp_path):
    """The demo's first point: the streams open after the command, the force stream's line
    unread until then.  Its first samples must not be ones made long before."""
    with clock_by_hand(tmp_path) as (emu, latency):
        for _ in range(3):  # 3 ticks, 240 kB of frames, while no driver has the line open
            emu.tick()
        t, clock = time.monotonic(), emu.next_index
        with force_stream(emu) as reads:
            emu.tick()  # the next frames (a reader that finds the line empty notes nothing)
            live = reads.live_after(t)
    assert live + latency >= clock, (live, latency, clock)  # was live 3000-6000, clock 60000


def test_no_tick_is_made_while_an_earlier_ones_frames_wait_in_the_emulator(tmp_path):
    """The port's writer thread short of CPU, the reader too while a tick is sent: the tick's
    frames beyond the 12 kB the line takes wait in the emulator, unseen by the reader, which then
    empties its line.  The clock may not make the next tick (a command landing then would be
    placed by that reader) until they are on the line."""
    with clock_by_hand(tmp_path) as (emu, _), force_stream(emu) as reads:
        line = emu.charge_amp.stream
        line.send_timeout_s = HANG_S  # only a hang drops the backlog here
        starved = threading.Event()
        line.port.flush = lambda: starved.wait(HANG_S)  # the port's writer thread gets no CPU
        waiting: list[int] = []  # bytes in the emulator's backlog as each tick is made (a tap runs
        emu.taps.append(lambda block: waiting.append(len(line.port._pending)))  # before the sending)
        try:
            reads.running.clear()
            emu.tick()  # the line takes 12 kB of the tick's 80; the rest waits in the emulator
            reads.running.set()  # the reader takes the 12 kB, and finds the line empty
            emu.tick()
        finally:
            reads.running.set()
            starved.set()
    assert waiting == [0, 0]  # was [0, ~62 kB]: 15 000 samples older than the newest tick, unseen
    assert line.port.dropped_bytes == 0  # the wait pushed them; none was lost
