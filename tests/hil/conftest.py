"""Hardware-in-the-loop fixtures: the whole stack (bench file -> drivers -> emulators -> one rig).

``hil`` starts an emulated bench from a bench file written here (the shipped one, with faster
back-off so fault tests stay short) and opens the drivers' Bench on it.  A tap records every rig
block, the truth against which samples that came through the drivers are checked.

Nothing here waits on wall time: tests wait for the emulator's sample clock to reach an index
(``Hil.wait_clock``), for a condition the clock's blocks make true (``Hil.wait_for``), or acquire
until the samples they need have come (``acquire_through``).  The timeouts only turn a hang into a
failure.  A fault placed at a sample index ahead of the clock is placed from the clock's own thread
(``arm_ahead``), so the clock cannot pass the index while the test's thread waits for the CPU.
Where a measurement begins is a sample index too: the one where the output came on
(``switched_on_at``, from the emulator's log of the rig's settings), not "whatever arrives after
start_output() returned" (``skip_to``).  And the streams' stall timeout is a hang bound
(``STALL_S``): the emulated instruments share the machine's CPU, so a busy machine holds their
clock as long as it likes.
"""

from __future__ import annotations

import re
import threading
from pathlib import Path
from typing import Callable

import numpy as np
import pytest

from hystbench.analysis.method import MethodDelays, measure_delays
from hystbench.blocks import BlockFlags, SampleBlock, concatenate
from hystbench.drivers.bench import Bench
from hystbench.drivers.protocols.bench_config import DEFAULT_BENCH, load_bench_config
from hystbench.formats.recording import Recording
from hystbench.sim_backend.emulators.bench import EmulatedBench
from hystbench.sim_backend.rig import SimulatedRig

FAST = {"initial_s": "0.02", "factor": "2.0", "max_s": "0.1", "attempts": "4"}
HANG_S = 120.0  # a safety timeout: only a hang takes this long
#: The ``hil`` fixtures' ``[bench] stall_timeout_s``: only a hang.  With the shipped 0.5 s, a busy
#: machine that held the emulator's clock thread for half a second looked like a pulled cable: the
#: streams reconnected, the frames sent meanwhile were lost, and a test expecting every sample saw
#: a gap.  A held clock is no stalled cable (test_hil_pacing); the tests of stall detection set
#: ``bench.stall_timeout_s`` themselves.
STALL_S = HANG_S
#: The ``hil`` fixtures' amplifier watchdog (``[current_amplifier.settings] watchdog_s``), counted on the
#: emulator's sample clock.  With the shipped 0.5 s (five heartbeats), a run of ``make test`` beside two
#: busy loops once starved the heartbeat thread for half a second of samples while the clock went on:
#: the amplifier latched WATCHDOG in the middle of a digitiser test.  Twenty heartbeats leave a busy
#: machine room; the watchdog test trips it as before, two seconds of samples after the host falls silent.
WATCHDOG_S = 2.0
#: The ``hil`` fixtures' ``[bench] timeout_s``, every command's reply deadline.  With the shipped 1 s, a
#: run of ``make test`` in a slow hour of the host (four workers on two cores) once had the emulated
#: digitiser answer its first ``SYST:ERR?`` later than that, and the bench faulted before a sample.  The
#: tests of a silent instrument set that instrument's own ``timeout_s``.
REPLY_S = 3.0


def bench_file(tmp_path: Path, **edits: str) -> Path:
    """The shipped bench.toml with ``table.key = value`` edits (keys must exist in the file or be
    commented out there), written to tmp_path."""
    text = DEFAULT_BENCH.read_text()
    for k, v in FAST.items():
        text = re.sub(rf"(?m)^{k} = .*$", f"{k} = {v}", text, count=1)
    for dotted, value in edits.items():
        table, key = dotted.rsplit(".", 1)
        section = re.search(rf"(?ms)^\[{re.escape(table)}\][^\n]*\n(.*?)(?=^\[|\Z)", text)
        assert section, table
        body = section.group(1)
        if re.search(rf"(?m)^#? ?{key} = ", body):
            body = re.sub(rf"(?m)^#? ?{key} = .*$", f"{key} = {value}", body, count=1)
        else:
            body = f"{key} = {value}\n" + body
        text = text[:section.start(1)] + body + text[section.end(1):]
    path = tmp_path / "bench.toml"
    path.write_text(text)
    return path


class Truth:
    """Every rig block the emulated bench produced, by sample index."""

    def __init__(self) -> None:
        self.blocks: list[SampleBlock] = []

    def __call__(self, block: SampleBlock) -> None:
        self.blocks.append(block)

    def channel(self, name: str, first: int, n: int) -> np.ndarray:
        x = np.concatenate([b.channels[name] for b in self.blocks])
        k = first - self.blocks[0].first_index
        assert k >= 0 and k + n <= x.size
        return x[k:k + n]


class Hil:
    def __init__(self, path: Path) -> None:
        self.path = path
        self.config = load_bench_config(path)
        self.emu = EmulatedBench(self.config)
        self.truth = Truth()
        self._tick = threading.Condition()
        self.emu.taps += [self.truth, self._on_block]
        self.emu.start()
        self.bench = Bench(self.config.resolved(self.emu.addresses))

    def _on_block(self, block: SampleBlock) -> None:
        with self._tick:
            self._tick.notify_all()

    def wait_for(self, cond: Callable[[], object], what: str, timeout_s: float = HANG_S) -> None:
        """Wait until ``cond()`` holds, checked at every block of the sample clock (whatever thread
        makes it true: the clock keeps ticking)."""
        with self._tick:
            if not self._tick.wait_for(lambda: bool(cond()), timeout_s):
                raise AssertionError(f"{what}: not within {timeout_s:g} s (a hang)")

    def wait_clock(self, index: int) -> None:
        """Wait until the emulator has produced every sample before ``index``."""
        self.wait_for(lambda: self.emu.next_index >= index, f"the sample clock reaching {index}")

    def blocks_ahead(self, n_blocks: int) -> int:
        """A sample index no frame has been made for yet: ``n_blocks`` blocks past the clock."""
        return self.emu.next_index + n_blocks * self.emu.block_samples

    def arm_ahead(self, n_blocks: int, arm: Callable[[int], None]) -> int:
        """``arm(index)`` with ``index`` = ``blocks_ahead(n_blocks)``, on the clock thread (see
        :func:`arm_ahead`).  Returns ``index``."""
        return arm_ahead(self.emu, n_blocks, arm)

    def close(self) -> None:
        try:
            self.bench.close()
        finally:
            self.emu.close()


def arm_ahead(emu: EmulatedBench, n_blocks: int, arm: Callable[[int], None]) -> int:
    """``arm(index)`` with ``index`` ``n_blocks`` clock blocks past the emulator's clock, called on
    the clock thread between two of its blocks, so the clock cannot pass ``index`` before ``arm``
    returns.  From the test's thread, a busy machine can hold the test between reading the clock
    and arming a fault for longer than a few 10 ms ticks: the fault then lands later than the
    test says.  Returns ``index``."""
    done, at = threading.Event(), []

    def tap(block: SampleBlock) -> None:  # after the rig made ``block``, before it is sent
        if not at:
            at.append(block.end_index + n_blocks * emu.block_samples)
            arm(at[0])
            done.set()

    emu.taps.append(tap)
    try:
        assert done.wait(HANG_S), "the emulator's clock stopped"
    finally:
        emu.taps.remove(tap)
    return at[0]


def wait_clock(emu: EmulatedBench, index: int) -> None:
    """Wait, on the clock's own blocks, until the emulator has made every sample before ``index``
    (for an emulator no ``Hil`` wraps: a ``BenchSource``'s, or one a test builds)."""
    reached = threading.Event()
    tap = lambda block: reached.set() if block.end_index >= index else None  # noqa: E731
    emu.taps.append(tap)
    try:
        assert emu.next_index >= index or reached.wait(HANG_S), "the emulator's clock stopped"
    finally:
        emu.taps.remove(tap)


def merge_runs(runs: list[SampleBlock]) -> list[SampleBlock]:
    """Runs of several ``acquire`` calls (which go on where the last stopped) as one call's runs."""
    out: list[SampleBlock] = []
    for r in runs:
        if out and r.first_index == out[-1].end_index:
            prev = out[-1]
            out[-1] = SampleBlock(prev.first_index, prev.fs_hz, concatenate([prev, r]).channels,
                                  flags=prev.flags | (r.flags & ~BlockFlags.GAP), gap_samples=prev.gap_samples,
                                  meta=prev.meta)
        else:
            out.append(r)
    return out


def switched_on_at(hil: "Hil") -> int:
    """The first sample index the rig made with the output on, the last time it came on (the
    emulator's log of the rig's settings, kept on the sample clock)."""
    changes = list(hil.emu.changes)
    assert changes and changes[-1][1]["output"], "the output is off"
    k = len(changes) - 1
    while k > 0 and changes[k - 1][1]["output"]:
        k -= 1
    return changes[k][0]


def skip_to(hil: "Hil", index: int) -> None:
    """Acquire and drop every aligned sample before ``index``: the next acquire starts there (or
    where the streams began, if later).  After a change, frames the clock made before it can still
    arrive: the clock thread can make a block, be held by a busy machine while start_output()
    returns and the streams open, and only then send it (the generator's monitor at 0 V, the
    output was off).  They show the bench as it was, not the measurement that follows."""
    bench = hil.bench
    while bench.next_index is None or bench.next_index < index:
        n = 1 if bench.next_index is None else index - bench.next_index
        bench.acquire(n / bench.config.fs_hz, timeout_s=HANG_S)


def acquire_through(hil: "Hil", index: int, chunk_s: float = 0.05) -> list[SampleBlock]:
    """Acquire until the samples reach past ``index`` (so a fault placed before it is inside)."""
    runs: list[SampleBlock] = []
    while not runs or runs[-1].end_index <= index:
        runs += hil.bench.acquire(chunk_s, timeout_s=HANG_S)
    return merge_runs(runs)


@pytest.fixture
def hil_factory(tmp_path):
    made: list[Hil] = []

    def make(*, extra: str = "", **edits: str) -> Hil:
        """A bench on the shipped file with ``edits`` (dotted keys) and ``extra`` TOML appended."""
        path = bench_file(tmp_path, **{"bench.stall_timeout_s": f"{STALL_S:g}", "bench.timeout_s": f"{REPLY_S:g}",
                                       "current_amplifier.settings.watchdog_s": f"{WATCHDOG_S:g}", **edits})
        if extra:
            path.write_text(path.read_text() + extra)
        h = Hil(path)
        made.append(h)
        h.bench.open()
        return h

    yield make
    for h in made:
        h.close()


@pytest.fixture
def hil(hil_factory):
    return hil_factory()


def expected_wire(hil: Hil, name: str, first: int, n: int) -> np.ndarray:
    """What the drivers must deliver for channel ``name``: the rig's samples through each
    instrument's scaling and the float32 wire, scaled back."""
    cfg = hil.config.instruments
    x = hil.truth.channel(name, first, n)
    if name == "force_N":
        s = cfg["charge_amplifier"].settings["scale_n_per_v"]
        return (x / s).astype(np.float32).astype(float) * s
    if name == "flux_Wb":
        g = cfg["flux_integrator"].settings["gain_v_per_wb"]
        return (x * g).astype(np.float32).astype(float) / g
    return x.astype(np.float32).astype(float)


def assert_the_rigs_delays(channels: dict[str, np.ndarray], fs_hz: float, meta: dict, rig: str, seed: int,
                           effects: dict | None = None) -> MethodDelays:
    """The paper's three delays from samples that came through the bench, against the same estimate
    on the rig's own output (same rig, seed and effects, 320 Hz, 1.4 A-pp, 1 s): within 5 standard
    errors of the two plus 10 ns (quantisation and wire rounding).  Returns the bench's estimate."""
    got = measure_delays(Recording(None, fs_hz, {k: channels[k] for k in ("current_A", "force_N", "flux_Wb")},
                                   dict(meta)))
    direct_rig = SimulatedRig(rig, fs_hz=fs_hz, seed=seed, frequency_hz=320.0, current_pp_a=1.4,
                              **({} if effects is None else {"effects": dict(effects)}))
    direct = measure_delays(Recording(None, fs_hz, dict(direct_rig.record(1.0).channels), direct_rig.metadata()))
    for name in ("hysteresis", "instrument", "total"):
        tol = 5 * np.hypot(got.delays_std_s[name], direct.delays_std_s[name]) + 10e-9
        assert got.delays_s[name] == pytest.approx(direct.delays_s[name], abs=tol), name
    return got
