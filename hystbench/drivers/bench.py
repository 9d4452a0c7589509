"""The four instruments as one bench: opened from a bench file, kept safe, streamed in step.

Safety first, always in this order: on a fault (amplifier fault bits, a lost connection, a
command error) and at shutdown, the generator output goes off and the amplifier is disabled,
both attempted independently, *before* anything else happens (reconnecting, raising, closing).
A heartbeat thread polls every instrument (which also feeds the amplifier's watchdog), so a fault
is acted on within ``heartbeat_s`` even when nobody is calling the bench.

The instruments come from the ``drivers.BACKENDS`` table, each built by its own class from its
table of the bench file; the bench treats them alike (``gate``, ``setup``, ``heartbeat``: see
``drivers.base``), so it has no branch per instrument.

The four streams are aligned once, from the moment they open, by the one acquisition loop,
:meth:`Bench.read_aligned`: every turn moves every sample the streams hold into the one aligner
(nothing is left behind in a stream's queue to pile up), then waits on the stream the aligner needs.
``acquire`` (a duration of samples, with a timeout) and the pipeline's ``BenchSource`` (blocks for
ever, with the operating point) both turn it, so consecutive calls hand out consecutive samples.

One way tells where a command's effect starts, whoever sent it: the sender says so
(:meth:`Bench.commanded`), and :meth:`Bench.change_index` is then the first sample that may show it
(the first live sample after the command, once the streams' readers have caught up, plus what was
still on its way).  Nothing is lost to learn it: the pipeline's source marks the samples before it
(and the instruments' response after it) as settling; ``acquire(..., since_command=True)`` (the
compensator's actuation, the demo) starts there, passing over the old samples on purpose, counted.
"""

from __future__ import annotations

import contextlib
import math
import threading
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Iterator

from ..blocks import BlockFlags, SampleBlock, concatenate
from ..deadline import Deadline
from ..errors import ConnectionLost, InstrumentError, InstrumentTimeout
from . import instrument_class
from .align import StreamAligner
from .base import FaultLatched, Instrument, log
from .protocols.bench_config import BenchConfig
from .safety import CurrentBudget, SafetyLimitError
from .stream import SampleStream

if TYPE_CHECKING:
    from .charge_amplifier import ChargeAmplifier
    from .current_amplifier import ModbusCurrentAmplifier
    from .flux_integrator import CanFluxIntegrator
    from .signal_generator import ScpiSignalGenerator

__all__ = ["Bench", "BenchFault", "build_instruments", "timeout_reason"]

_STEP_S = 0.05  # the longest one turn of the acquisition loop waits for a stream
#: the longest ``wait_change`` waits for the streams' readers to catch up with the instruments
CATCH_UP_S = 5.0


@dataclass(frozen=True)
class BenchFault:
    """A fault the bench acted on, kept so it can be reported after the output went off first."""

    t_monotonic: float
    instrument: str
    message: str
    output_off: bool  # whether switching the output off was confirmed
    error: BaseException | None = None  # what was raised, kept as the cause of what the bench raises later


def build_instruments(config: BenchConfig, budget: CurrentBudget) -> dict[str, Instrument]:
    """One driver per instrument, from a resolved bench config (addresses filled in): the class
    ``drivers.BACKENDS`` names for the table, built by its ``from_config``.  Opens nothing."""
    return {name: instrument_class(name).from_config(inst, config, budget)
            for name, inst in config.instruments.items()}


class Bench:
    """``with Bench(config.resolved(addresses)) as bench: bench.start_output(); bench.acquire(1.0)``"""

    def __init__(self, config: BenchConfig) -> None:
        self.config = config
        gain = float(config.instruments["current_amplifier"].settings.get("gain_a_per_v", 0.5))
        self.budget = CurrentBudget(config.max_current_a, gain, margin=config.current_margin)
        self.instruments = build_instruments(config, self.budget)
        self.generator: ScpiSignalGenerator = self.instruments["signal_generator"]  # type: ignore[assignment]
        self.amplifier: ModbusCurrentAmplifier = self.instruments["current_amplifier"]  # type: ignore[assignment]
        self.charge_amp: ChargeAmplifier = self.instruments["charge_amplifier"]  # type: ignore[assignment]
        self.integrator: CanFluxIntegrator = self.instruments["flux_integrator"]  # type: ignore[assignment]
        self.faults: list[BenchFault] = []
        self.streams: dict[str, SampleStream] = {}
        self._aligner: StreamAligner | None = None  # the streams' samples on the common clock
        self._delivered = dict.fromkeys([*self.instruments, "digitiser"], 0)  # samples each stream gave, ever
        self.discarded_samples = 0  # passed over by acquire(since_command=True) (samples of the common clock)
        self._commanded_at: float | None = None  # the last command's time, until its change_index is known
        self._change: int | None = None  # the first sample that may show the last command
        #: samples made before a moment that may still arrive after the readers caught up then
        self.latency_samples = math.ceil(config.latency_s * config.fs_hz - 1e-9)
        self._fault_lock = threading.Lock()
        self._stop = threading.Event()
        self._heartbeats: list[threading.Thread] = []
        self.heartbeat_paused = threading.Event()  # tests: stop feeding the watchdog (see pause_heartbeat)
        self._polling = {name: threading.Lock() for name in self.instruments}  # held while a poll runs

    # --- life cycle --------------------------------------------------------------------------------
    def open(self) -> "Bench":
        """Open every instrument, the gate (the amplifier) first and disabled at once; then set
        each up from the file (its settings, and the state the bench measures in)."""
        try:
            gates_first = sorted(self.instruments.items(), key=lambda item: not item[1].gate)
            for name, inst in gates_first:
                inst.open()
                if inst.gate and not inst.safe_off():
                    raise InstrumentError(f"{name}: could not be disabled after opening; the bench does not open")
            for name, inst in self.config.instruments.items():
                self.instruments[name].setup(dict(inst.settings))
        except BaseException:
            self.close()
            raise
        self._stop.clear()
        self._heartbeats = [threading.Thread(target=self._beat, args=(name,), name=f"heartbeat-{name}", daemon=True)
                            for name in self.instruments]  # one each: a slow instrument starves no other poll
        for t in self._heartbeats:
            t.start()
        return self

    def close(self) -> None:
        """Output off first; then streams, heartbeat and connections."""
        self.safe_off()
        self._stop.set()
        for t in self._heartbeats:
            t.join(timeout=2.0)
        self._heartbeats = []
        self.close_streams()
        for inst in self.instruments.values():
            inst.close()

    def __enter__(self) -> "Bench":
        return self.open()

    def __exit__(self, *exc: object) -> None:
        self.close()

    # --- safety --------------------------------------------------------------------------------------
    def safe_off(self) -> bool:
        """Generator output off and amplifier disabled, each tried regardless of the other."""
        ok_gen = self.generator.safe_off() if self.generator.is_open else False
        ok_amp = self.amplifier.safe_off() if self.amplifier.is_open else False
        return ok_gen or ok_amp  # either one stops the coil current

    def _fault(self, instrument: str, message: str, error: BaseException | None = None) -> BenchFault:
        off = self.safe_off()  # before anything else
        fault = BenchFault(time.monotonic(), instrument, message, off, error)
        with self._fault_lock:
            self.faults.append(fault)
        log.error("bench fault on %s: %s (output off: %s)", instrument, message, off)
        return fault

    def raise_if_faulted(self) -> None:
        with self._fault_lock:
            fault = self.faults[-1] if self.faults else None
        if fault is not None:
            raise InstrumentError(f"bench stopped: {fault.instrument}: {fault.message} "
                                  f"(output switched off: {fault.output_off}); clear_faults() to go on") from fault.error

    def clear_faults(self) -> None:
        self.amplifier.clear_faults()
        with self._fault_lock:
            self.faults.clear()

    @contextlib.contextmanager
    def guarded(self, instrument: str) -> Iterator[None]:
        """Any instrument error inside switches the output off, is recorded, and is re-raised."""
        try:
            yield
        except SafetyLimitError:
            raise  # refused before anything was sent: the bench is as it was
        except InstrumentError as err:
            self._fault(instrument, str(err), err)
            raise

    def start_output(self) -> None:
        """Amplifier enabled, then generator output on (refused while a fault is recorded)."""
        self.raise_if_faulted()
        with self.guarded("current_amplifier"):
            self.amplifier.enable()
        with self.guarded("signal_generator"):
            self.generator.set_output(True)

    def configure(self, instrument: str, **settings: Any) -> None:
        with self.guarded(instrument):
            self.instruments[instrument].configure(**settings)

    def reconnect(self, instrument: str) -> None:
        """Reopen one instrument with back-off; its output comes back off."""
        self.close_streams()  # streams are reopened by the next acquire
        with self.guarded(instrument):
            self.instruments[instrument].reconnect()

    # --- heartbeat -------------------------------------------------------------------------------------
    def _beat(self, name: str) -> None:
        failures = 0
        inst = self.instruments[name]
        while not self._stop.wait(self.config.heartbeat_s):
            with self._polling[name]:
                if self.heartbeat_paused.is_set() or self.faults or not inst.is_open:
                    continue
                try:
                    inst.heartbeat()
                    failures = 0
                except ConnectionLost as err:
                    self._fault(name, str(err), err)
                    self._try_reconnect(name)
                except InstrumentError as err:
                    failures += 1
                    if failures >= 2 or isinstance(err, FaultLatched):  # one missed poll may be noise
                        self._fault(name, str(err), err)
                        failures = 0

    def pause_heartbeat(self) -> None:
        """Stop polling, and return once no poll is in flight (so the next command on any
        instrument is the caller's own).  ``heartbeat_paused.clear()`` resumes."""
        self.heartbeat_paused.set()
        for lock in self._polling.values():
            with lock:
                pass

    def _try_reconnect(self, name: str) -> None:
        try:
            self.instruments[name].reconnect()
            log.warning("bench: %s reconnected; output stays off until clear_faults() and start_output()", name)
        except InstrumentError as err:
            log.error("bench: %s did not come back: %s", name, err)

    # --- streams ---------------------------------------------------------------------------------------
    def open_streams(self) -> dict[str, SampleStream]:
        """Start the four sample streams (generator command_V, amplifier current_A, charge amplifier
        force_N, integrator flux_Wb)."""
        if not self.streams:
            # a silence as long as a burst's spacing (an emulated clock tick) is no stall
            kw = dict(stall_timeout_s=self.config.stall_timeout_s + self.config.latency_s)
            if self.config.digitiser is not None:  # one digitiser samples the four signals (issue 15)
                from .digitiser import open_digitiser_stream

                with self.guarded("digitiser"):
                    self.streams["digitiser"] = open_digitiser_stream(self.config, **kw)
                self._aligner = StreamAligner(self.streams)
                return self.streams
            for name, inst in self.instruments.items():
                with self.guarded(name):
                    self.streams[name] = inst.open_stream(skew_s=self.config.instruments[name].skew_s, **kw)
            self._aligner = StreamAligner(self.streams)
        return self.streams

    def close_streams(self) -> None:
        for s in self.streams.values():
            s.close()
        self.streams = {}
        self._aligner = None

    @property
    def next_index(self) -> int | None:
        """The sample index the next aligned block starts at (None before the first one)."""
        return None if self._aligner is None else self._aligner.cursor

    def live_index_after(self, t: float) -> int | None:
        """A sample index at or past the common clock at monotonic time ``t``, bar what was on the
        wire then (the streams' :meth:`~.stream.SampleStream.live_index_after`; every stream's
        bounds the one clock, the smallest is kept); None until a stream's reader has caught up
        with its transport since ``t``.  After a command sent at ``t``, samples past it show the
        command's effect however far behind the reading was."""
        found = [i for s in self.streams.values() if (i := s.live_index_after(t)) is not None]
        return min(found) if found else None

    def commanded(self) -> None:
        """Note that a command to the instruments (a new sine or waveform, the output on or off) has
        just been sent: :meth:`change_index` is unknown until the streams tell where it starts."""
        self._commanded_at = time.monotonic()
        self._change = None

    def change_index(self) -> int | None:
        """The first sample that may show the last command (:meth:`commanded`): the common clock at
        the command, as the streams' readers place it once caught up with their transports
        (:meth:`live_index_after`: however far behind the reading was), plus what may still have
        been on its way then (``latency_samples``: the instruments' buffers, the emulated rig's
        tick).  None before any command and until a reader has caught up since; then kept.  Asking
        reads nothing and drops nothing (the acquisition loop's turns read the streams)."""
        if self._commanded_at is not None and (live := self.live_index_after(self._commanded_at)) is not None:
            self._change, self._commanded_at = live + self.latency_samples, None
        return self._change

    def wait_change(self, timeout_s: float | None = None) -> int | None:
        """:meth:`change_index`, waiting for it: the streams are read into the aligner meanwhile (not
        handed out, not dropped).  None if no command was noted.  Raises ``InstrumentTimeout`` if
        no reader catches up within ``timeout_s`` (default :data:`CATCH_UP_S`): what follows
        could not be told from the old."""
        self.open_streams()
        deadline = Deadline(CATCH_UP_S if timeout_s is None else timeout_s)
        while (change := self.change_index()) is None and self._commanded_at is not None:
            if deadline.expired:
                raise InstrumentTimeout(f"bench: after a change, no stream's reader caught up with its "
                                        f"instrument within {deadline.elapsed:.2g} s: the samples that follow "
                                        "cannot be told from the old ones (is the machine overloaded?)")
            self._read_stream(self._aligner.waiting_for(), deadline.left(_STEP_S))
        self._drain()
        return change

    def _read_stream(self, name: str, timeout_s: float) -> bool:
        """Move one block of stream ``name`` into the aligner, waiting up to ``timeout_s``; False if
        none came.  A stream that is lost is a fault: the output goes off first, then it raises."""
        try:
            block = self.streams[name].read(timeout_s=timeout_s)
        except InstrumentError as err:
            self._fault(name, str(err), err)
            raise
        if block is None:
            return False
        self._aligner.push(name, block)
        self._delivered[name] += block.n
        return True

    def _drain(self) -> None:
        """Move every block the streams hold into the aligner."""
        for name in self.streams:
            while self._read_stream(name, 0.0):
                pass

    def read_aligned(self, max_samples: int | None = None, *, timeout_s: float = _STEP_S,
                     min_samples: int = 1, gather_s: float | None = None) -> SampleBlock | None:
        """One turn of the acquisition loop: the next aligned block of every channel (at most
        ``max_samples``), or None if none came within ``timeout_s``.

        ``min_samples``: the block is gathered until it holds that many (or ``max_samples``, if
        fewer): every block costs each pipeline stage its per-block overhead, and the streams'
        runs come in pieces of a few hundred samples.  It ends early where a gap follows (the
        block stays contiguous; the next one starts with the GAP) or once ``gather_s`` (default
        ``timeout_s``) passed after its first samples came (a stalled stream holds up what
        already came no longer).

        Every stream is drained into the one aligner first, so nothing piles up in a stream's
        queue however long the caller computed; then, if the aligner has no block yet, the turn
        waits on the stream the aligner waits for.  Blocks follow on from the last one handed out;
        one after missing samples has ``BlockFlags.GAP`` and the exact ``gap_samples``.  A recorded
        fault, or a stream that cannot be reconnected, raises (with the output already off)."""
        self.raise_if_faulted()
        self.open_streams()
        self._drain()
        block = self._aligner.pop(max_samples)
        if block is None and timeout_s > 0 and self._read_stream(self._aligner.waiting_for(), timeout_s):
            self._drain()
            block = self._aligner.pop(max_samples)
        want = min_samples if max_samples is None else min(min_samples, max_samples)
        if block is None or block.n >= want:
            return block
        return self._gathered(block, want, max_samples, Deadline(timeout_s if gather_s is None else gather_s))

    def _gathered(self, block: SampleBlock, want: int, max_samples: int | None, deadline: Deadline) -> SampleBlock:
        """``block`` and the samples that follow it without a gap, once there are ``want`` of them in
        all (or a gap ends the run, or the deadline passes): one contiguous block."""
        al = self._aligner
        while True:
            n, ended = al.contiguous()
            if block.n + n >= want or ended or deadline.expired:
                break
            try:
                if not self._read_stream(al.waiting_for(), deadline.left()):
                    break
                self._drain()
            except InstrumentError:  # a fault, recorded (output off): what came goes out; the next turn raises
                break
        take = n if max_samples is None else min(n, max_samples - block.n)
        return block if take <= 0 else concatenate([block, al.take(take)])

    def acquire(self, duration_s: float, *, timeout_s: float | None = None,
                since_command: bool = False) -> list[SampleBlock]:
        """The next ``duration_s`` worth of aligned samples of every channel, as contiguous runs.

        ``since_command``: none made before the last command (:meth:`commanded`) took effect: the
        samples before its :meth:`change_index` (samples of the bench as it was, however long the
        caller computed or far behind the reading fell) are passed over, on purpose and counted
        in ``discarded_samples``; the first run then starts at the change, consecutive with the
        last sample handed out but for those (a gap only if a stream really lost samples).  Waits
        for the change as :meth:`wait_change` does.

        Missing samples are never filled in: the first run of the first call starts where all
        streams have begun; each later run has ``BlockFlags.GAP`` and ``gap_samples`` = the exact
        number of indices missing before it.  The next call goes on where this one stopped.  A
        recorded fault, or a stream that cannot be reconnected, raises (with the output already
        off); so does ``timeout_s`` (default 3 x duration + 5 s) passing, saying why."""
        self.raise_if_faulted()
        n_want = int(round(duration_s * self.config.fs_hz))
        if since_command and (change := self.wait_change()) is not None:
            self.discarded_samples += self._aligner.skip_to(change)
        deadline = Deadline(timeout_s if timeout_s is not None else 3 * duration_s + 5.0)
        self.open_streams()
        before = dict(self._delivered)
        got: list[SampleBlock] = []
        have = 0
        while have < n_want:
            block = self.read_aligned(n_want - have, timeout_s=deadline.left(_STEP_S))
            if block is not None:
                got.append(block)
                have += block.n
            elif deadline.expired:
                counts = {name: self._delivered[name] - before[name] for name in self.streams}
                raise InstrumentTimeout(timeout_reason(have, n_want, deadline.elapsed, counts, self.config.fs_hz,
                                                       emulated=self.config.any_sim, ends=self._aligner.ends()))
        return _runs(got)

    def stream_stats(self) -> dict[str, dict[str, int]]:
        return {name: s.stats.as_dict() for name, s in self.streams.items()}


def timeout_reason(have: int, n_want: int, waited_s: float, counts: dict[str, int], fs_hz: float, *,
                   emulated: bool, ends: dict[str, int | None] | None = None) -> str:
    """Why an acquisition ran out of time, and what to do about it (one line).

    ``counts``: samples each stream delivered meanwhile; ``ends``: one past each stream's newest
    sample.  The usual cause on a busy machine is the emulated bench running slower than real time
    (it needs most of a core at 100 kS/s): the streams then deliver less than ``fs_hz`` per second."""
    head = f"bench: only {have} of {n_want} aligned samples within {waited_s:.1f} s"
    silent = [name for name, n in counts.items() if n == 0]
    if silent and emulated and len(silent) == len(counts):
        return (f"{head}: the emulated bench produced no samples at all meanwhile: the machine is far too busy "
                "to run it (it needs most of a core at 100 kS/s), or its clock stopped; free CPU and retry")
    if silent:
        return (f"{head}: {', '.join(silent)} delivered no samples meanwhile (its stream is stalled: check the "
                f"instrument, its stream address and its cable)")
    slowest = min(counts, key=lambda name: counts[name])
    rate = counts[slowest] / waited_s
    if rate < 0.9 * fs_hz:
        if emulated:
            why = (f"the emulated bench produced {counts[slowest]} samples in {waited_s:.1f} s, {rate / fs_hz:.0%} "
                   f"of real time at {fs_hz / 1e3:g} kS/s: this machine is too slow (CPU-bound) to run it in real "
                   "time; free CPU (stop other jobs), lower [bench] fs_hz, or allow a longer timeout")
        else:
            why = (f"{slowest} delivered {counts[slowest]} samples in {waited_s:.1f} s, {rate / fs_hz:.0%} of "
                   f"[bench] fs_hz = {fs_hz:g}: check fs_hz against the instruments' sample rate, and the host's load")
        return f"{head}: {why}"
    if n_want / fs_hz > waited_s:
        return (f"{head}: the streams keep real time, but {n_want / fs_hz:g} s of samples take {n_want / fs_hz:g} s "
                "to come: allow a longer timeout")
    return (f"{head}: the streams deliver at the sample rate but their sample indices do not meet (end of each "
            f"stream's samples: {ends}): a stream does not count the common sample clock")


def _runs(blocks: list[SampleBlock]) -> list[SampleBlock]:
    """Merge consecutive contiguous blocks; each run keeps the GAP flag and count of its first block."""
    runs: list[SampleBlock] = []
    start = 0
    for i in range(1, len(blocks) + 1):
        if i == len(blocks) or blocks[i].first_index != blocks[i - 1].end_index:
            run = concatenate(blocks[start:i])
            flags = run.flags if blocks[start].gap_samples else run.flags & ~BlockFlags.GAP
            runs.append(SampleBlock(run.first_index, run.fs_hz, run.channels, flags=flags,
                                    gap_samples=blocks[start].gap_samples, meta=run.meta))
            start = i
    return runs
