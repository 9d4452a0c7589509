"""The bench sampled by one digitiser (issue 15): the emulated digitiser serves the rig's four
signals over SCPI on 127.0.0.1, read through real pyvisa-py by the drivers' Bench, checked sample
for sample against the rig, and the paper's three delays estimated from it against the rig's own,
to the tolerance of test_hil_stream."""

from __future__ import annotations

import numpy as np
import pytest

from hystbench.blocks import BlockFlags

from .conftest import HANG_S, STALL_S, Hil, acquire_through, assert_the_rigs_delays, skip_to, switched_on_at

pytestmark = pytest.mark.slow(15)  # ~15 s: handed to a worker before lighter files (tests/conftest.py)

SCALES = {"current_A": 0.2, "force_N": 50.0, "flux_Wb": 1e-5, "command_V": 1.0}  # SI per volt at the inputs
CHANNELS = {"generic": ("CHAN1", "CHAN2", "CHAN3", "CHAN4"), "tektronix": ("CH1", "CH2", "CH3", "CH4")}


def digitiser_table(dialect: str = "generic") -> str:
    chans = ", ".join(f'{s} = "{c}"' for s, c in zip(SCALES, CHANNELS[dialect]))
    scales = ", ".join(f"{s} = {v!r}" for s, v in SCALES.items())
    return f'\n[digitiser]\nbackend = "sim"\ndialect = "{dialect}"\nchannels = {{ {chans} }}\nscales = {{ {scales} }}\n'


@pytest.fixture
def dig_factory(hil_factory):
    def make(dialect: str = "generic", extra: str = "") -> Hil:
        return hil_factory(extra=digitiser_table(dialect) + extra)

    return make


def through_the_digitiser(hil: Hil, name: str, first: int, n: int) -> np.ndarray:
    """The rig's samples as the digitiser must deliver them, computed here: SI / scale volts at its
    input, 16-bit codes of 10/32768 V rounded and held at +-32767, times the scale again."""
    lsb = 10.0 / 32768
    volts = hil.truth.channel(name, first, n) / SCALES[name]
    return np.clip(np.round(volts / lsb), -32767, 32767) * lsb * SCALES[name]


def test_one_second_through_the_digitiser_and_the_papers_delays(dig_factory):
    hil = dig_factory()
    bench = hil.bench
    bench.start_output()
    on = switched_on_at(hil)
    skip_to(hil, on)
    runs = bench.acquire(1.1, timeout_s=HANG_S)
    assert len(runs) == 1, [(r.first_index, r.n, r.gap_samples) for r in runs]
    run = runs[0]
    assert run.first_index >= on and run.n == 110_000 and set(run.channels) == set(SCALES)
    assert not run.flags & (BlockFlags.GAP | BlockFlags.CLIP) and run.gap_samples == 0
    stats = bench.stream_stats()["digitiser"]
    assert stats["gap_samples"] == stats["reconnects"] == 0
    for name in SCALES:  # nothing lost, shifted or invented: the rig's samples through the 16-bit ADC
        np.testing.assert_allclose(run.channels[name], through_the_digitiser(hil, name, run.first_index, run.n),
                                   rtol=1e-12, atol=0, err_msg=name)

    sim = hil.config.sim
    got = assert_the_rigs_delays({k: x[10_000:] for k, x in run.channels.items()}, run.fs_hz, hil.emu.rig.metadata(),
                                 sim["rig"], sim["seed"], sim["effects"])
    assert got.delays_s["hysteresis"] > 0


def test_a_truncated_block_loses_its_segment_as_an_exact_gap(dig_factory):
    hil = dig_factory()
    emu, bench = hil.emu.digitiser, hil.bench
    bench.start_output()
    before = bench.acquire(0.02, timeout_s=HANG_S)[-1]
    sent = emu.faults.replies_sent
    emu.block_faults.append("truncate")  # the next data block stops half way: the driver times out in it
    hil.wait_for(lambda: not emu.block_faults, "the truncated block")
    runs = acquire_through(hil, hil.emu.next_index)
    gapped = [r for r in runs if r.flags & BlockFlags.GAP]
    assert len(gapped) == 1 and gapped[0].gap_samples > 0
    g = gapped[0]
    stats = bench.stream_stats()["digitiser"]
    assert stats["reconnects"] == 1 and stats["gap_samples"] == g.gap_samples and emu.faults.replies_sent > sent
    # the gap is what the runs skip: the run before ends where the gap begins
    prev = runs[runs.index(g) - 1] if runs.index(g) else before
    assert g.first_index - g.gap_samples == prev.end_index
    for r in runs:  # every sample delivered is the rig's, at its own index
        for name in SCALES:
            np.testing.assert_allclose(r.channels[name], through_the_digitiser(hil, name, r.first_index, r.n),
                                       rtol=1e-12, atol=0, err_msg=name)


def test_the_tektronix_dialect_through_the_emulator(dig_factory):
    hil = dig_factory("tektronix")
    hil.bench.start_output()
    run = hil.bench.acquire(0.05, timeout_s=HANG_S)[0]
    assert run.n == 5000
    assert any(m.startswith(b"CURV?") for m in hil.emu.digitiser.commands_seen)
    for name in SCALES:
        np.testing.assert_allclose(run.channels[name], through_the_digitiser(hil, name, run.first_index, run.n),
                                   rtol=1e-12, atol=0, err_msg=name)


class UntilMeasured:
    """A source's blocks until ``n`` samples with the output on and settled came: the bench settles
    only once its readers have caught up with the instruments, which a busy machine delays by seconds
    (a fixed 1.6 s record once kept 95 000 settled samples), so the record ends on that event."""

    def __init__(self, source, n: int) -> None:
        self.source, self.n = source, n
        self.name, self.channels, self.fs_hz = source.name, source.channels, source.fs_hz

    def __getattr__(self, name):  # bench, emu, set_output: the source's own
        return getattr(self.source, name)

    def metadata(self) -> dict:
        return self.source.metadata()

    def blocks(self, stop=None):
        settled = 0
        for b in self.source.blocks(stop):
            yield b
            p = b.point
            settled += b.n if p is not None and p.output_on and not p.settling else 0
            if settled >= self.n:
                return

    def close(self) -> None:
        self.source.close()


def test_the_daemons_source_records_and_estimates_from_the_digitiser(tmp_path):
    """The daemon's path: BenchSource (its [source] kind = "bench") on bench_digitiser.toml ->
    pipeline -> live estimates and an MCAP log; the method on the logged samples gives the rig's
    delays to the tolerance of test_hil_stream, as from the framed streams."""
    import re

    from hystbench.acquisition.record import record_log
    from hystbench.acquisition.sources import BenchSource
    from hystbench.blocks import concatenate
    from hystbench.config import CONFIG_DIR
    from hystbench.formats.mcaplog import iter_blocks

    text = (CONFIG_DIR / "bench_digitiser.toml").read_text()
    path = tmp_path / "bench.toml"
    path.write_text(re.sub(r"(?m)^stall_timeout_s = .*$", f"stall_timeout_s = {STALL_S:g}", text, count=1))
    n = 100_000
    src = UntilMeasured(BenchSource(str(path), excitation=(320.0, 1.4)), n)
    try:
        assert src.bench.config.digitiser is not None and src.emu.digitiser is not None
        src.set_output(True)
        res = record_log(src, tmp_path / "run.mcap", timeout_s=HANG_S)
    finally:
        src.close()
    logged = list(iter_blocks(res["log"][0]))
    assert res["samples"] == sum(b.n for b in logged) and res["estimates"]
    blocks = [b for b in logged if b.meta["output_on"] and not b.meta.get("settling")]
    assert not any(b.flags & BlockFlags.GAP for b in blocks)
    run = concatenate(blocks)
    assert run.end_index - run.first_index == run.n  # one contiguous run
    assert run.n >= n, run.n
    assert_the_rigs_delays({k: x[-n:] for k, x in run.channels.items()}, run.fs_hz, src.metadata(), "ecore_pm", 0)


def test_a_raw_socket_speaks_scpi_to_the_emulated_digitiser_and_reads_its_error_queue():
    """A program that is not ours (a raw socket) gets the standard replies: identity, sample rate,
    an empty segment before RUN, and each bad command as an entry of SYST:ERR?."""
    import socket

    from hystbench.config import CONFIG_DIR
    from hystbench.drivers.protocols.bench_config import load_bench_config
    from hystbench.sim_backend.emulators.bench import EmulatedBench

    with EmulatedBench(load_bench_config(CONFIG_DIR / "bench_digitiser.toml")) as emu:
        host, _, port = emu.addresses["digitiser"]["scpi_tcp"].rpartition(":")
        with socket.create_connection((host, int(port)), timeout=HANG_S) as s:
            buf = b""

            def ask(msg: bytes) -> bytes:
                nonlocal buf
                s.sendall(msg + b"\n")
                while b"\n" not in buf:
                    chunk = s.recv(4096)
                    assert chunk, "connection closed before a reply"
                    buf += chunk
                line, _, buf = buf.partition(b"\n")
                return line

            assert ask(b"*IDN?") == b"HYSTBENCH,SIMDIG-4,0001,1.0"
            assert float(ask(b":ACQuire:SRATe?")) == 100_000.0
            assert ask(b"WAV:SOUR CHAN3;:WAV:PRE?").split(b",")[2] == b"0"  # not RUN yet: nothing to read
            assert ask(b"WAV:DATA?") == b"#10"
            s.sendall(b"WAV:FORM FLOAT\nWAV:SOUR CHAN9\nMEASure:VOLTage?\n")
            assert ask(b"SYST:ERR?") == b'-224,"Illegal parameter value"'
            assert ask(b"SYST:ERR?") == b'-224,"Illegal parameter value"'
            assert ask(b"SYST:ERR?") == b'-113,"Undefined header"'
            assert ask(b"SYST:ERR?") == b'0,"No error"'


def test_a_hole_in_the_emulated_memory_ends_the_segment_nothing_is_shifted_across_it():
    """Review R1: while the digitiser is stopped (the stream's reopen sends STOP, then RUN) its
    memory has a hole.  A segment read across it must end there (the next one starts after it: a
    gap the driver sees), never carry the later samples at the earlier indices.  Each sample's code
    is its own index, so a shifted sample shows."""
    from hystbench.blocks import SampleBlock
    from hystbench.drivers.digitiser import ScpiDigitiser, VisaLink
    from hystbench.drivers.protocols import scpi_digitiser as sd
    from hystbench.sim_backend.emulators.digitiser import Y_INCREMENT, DigitiserEmulator

    emu = DigitiserEmulator(1e5, {s: (k, 1.0) for k, s in enumerate(SCALES, start=1)})

    def clock_block(first: int, n: int = 1000) -> None:
        volts = np.arange(first, first + n) * Y_INCREMENT  # code = index, exact
        emu.on_block(SampleBlock(first, 1e5, {s: volts for s in SCALES}))

    dig = ScpiDigitiser(VisaLink(emu.addresses["visa"], HANG_S), sd.dialect("generic"), 1e5)
    try:
        dig.open(("CHAN1",))
        clock_block(0)
        assert dig.fetch("CHAN1")[0] == 0
        clock_block(1000)  # not read yet when the acquisition stops
        dig.send("stop")
        clock_block(2000)  # not acquired: the hole
        dig.send("run")
        clock_block(3000)
        got = [dig.fetch("CHAN1") for _ in range(2)]
    finally:
        dig.close()
        emu.close()
    for (first, volts, _), want_first in zip(got, (1000, 3000)):
        assert first == want_first
        np.testing.assert_array_equal(np.round(volts / Y_INCREMENT), np.arange(want_first, want_first + 1000))


def test_a_digitiser_whose_rate_changed_ends_the_stream_with_the_reason_not_a_dead_reader():
    """Review R1: the rate changed on the instrument mid-run (e.g. its timebase turned): the points
    come 2/fs apart, the read is refused and the stream reopens, where the rate check refuses the
    session too.  That refusal (a ConfigError at the first open) must be one more failed attempt on
    a reopen, so the stream ends with the reason; escaping the reader thread it left the stream
    silent, no error, and a traceback on stderr."""
    from hystbench.blocks import SampleBlock
    from hystbench.drivers.base import Backoff
    from hystbench.drivers.digitiser import DigitiserFrameSource, ScpiDigitiser, VisaLink
    from hystbench.drivers.protocols import scpi_digitiser as sd
    from hystbench.drivers.stream import SampleStream
    from hystbench.errors import ConnectionLost
    from hystbench.sim_backend.emulators.digitiser import DigitiserEmulator

    emu = DigitiserEmulator(1e5, {s: (k, 1.0) for k, s in enumerate(SCALES, start=1)})
    link = VisaLink(emu.addresses["visa"], HANG_S)
    src = DigitiserFrameSource(ScpiDigitiser(link, sd.dialect("generic"), 1e5), ["CHAN1", "CHAN2", "CHAN3", "CHAN4"],
                               poll_s=0.001)
    stream = SampleStream("digitiser", src, list(SCALES), 1e5, stall_timeout_s=HANG_S,
                          backoff=Backoff(initial_s=0.001, factor=1.0, max_s=0.001, attempts=2)).start()
    try:
        emu.on_block(SampleBlock(0, 1e5, {s: np.zeros(1000) for s in SCALES}))
        assert stream.read(timeout_s=HANG_S).first_index == 0
        emu.fs_hz = 5e4  # the instrument now samples at half the bench's clock
        emu.on_block(SampleBlock(1000, 1e5, {s: np.zeros(1000) for s in SCALES}))
        with pytest.raises(ConnectionLost, match=r"not one period of the 100000 Hz clock.*2 reconnection attempts"):
            while stream.read(timeout_s=HANG_S) is not None:
                pass
    finally:
        stream.close()
        emu.close()


def test_segmented_acquisition_through_pyvisa_py_places_segments_exactly_and_gives_the_rigs_delays(dig_factory):
    """Review R1: an oscilloscope's segmented memory (acquisition = "segmented"), one batch of 3
    segments armed at a time, each triggered at a period start of the generator.  Within a batch
    every segment is at the index its time tag says (the rig's samples there, the emulator's true
    triggers apart); between batches the gap is the host clock's estimate, flagged as such; the
    paper's delays from one segment equal the rig's."""
    hil = dig_factory(extra='acquisition = "segmented"\nsegments = 3\n')
    emu, bench = hil.emu.digitiser, hil.bench
    emu.segment_points = 24_000  # 76.8 periods of 320 Hz: the next trigger comes after a gap (25 000 would be 80)
    bench.start_output()
    runs = bench.acquire(1.2, timeout_s=HANG_S)  # 120 000 samples: batch 1 (72 000) and part of batch 2
    assert len(emu.triggers) >= 2
    n_seg = emu.segment_points
    assert [r.n for r in runs[:4]] == [n_seg] * 4
    batch1, batch2 = emu.triggers[0], emu.triggers[1]
    assert [r.first_index - runs[0].first_index for r in runs[:3]] == [t - batch1[0] for t in batch1]
    assert not runs[1].flags & BlockFlags.GAP_ESTIMATED and runs[1].gap_samples == batch1[1] - batch1[0] - n_seg
    assert runs[3].flags & BlockFlags.GAP and runs[3].flags & BlockFlags.GAP_ESTIMATED and runs[3].gap_samples >= 1
    stats = bench.stream_stats()["digitiser"]
    assert stats["estimated_gaps"] >= 1 and 0 < stats["estimated_gap_samples"] < stats["gap_samples"]
    for r, true_first in zip(runs[:4], batch1 + batch2[:1]):  # the rig's samples, from each true trigger
        for name in SCALES:
            np.testing.assert_allclose(r.channels[name], through_the_digitiser(hil, name, true_first, r.n),
                                       rtol=1e-12, atol=0, err_msg=name)

    seg = runs[3]  # a segment of the second batch: the output has settled
    sim = hil.config.sim
    assert_the_rigs_delays(seg.channels, seg.fs_hz, hil.emu.rig.metadata(), sim["rig"], sim["seed"], sim["effects"])
