"""Sources of the pipeline: where sample blocks come from, and the commands that drive the bench.

A *source* yields :class:`SampleBlock` s (the :class:`Source` protocol); sources that drive the
bench also take commands (:class:`Controllable`), applied between blocks so that every block has
one operating point, stated in its ``meta`` (``frequency_hz``, ``current_pp_a``, ``offset_a``,
``output_on``, ``table``).  Logs keep that meta, so a replay cuts windows where the live run did.

- :class:`RigSource` — the simulated rig directly;
- :class:`SyntheticSource` — precomputed blocks replayed from memory (benchmarks, fast tests);
- :class:`~.mcaplog.McapSource` — a log (``replay``);
- the drivers' bench (emulated or real instruments): see :func:`bench_source`.
"""

from __future__ import annotations

import math
import threading
import time
from typing import TYPE_CHECKING, Any, Callable, Iterator, Mapping, Protocol, runtime_checkable

import numpy as np
from numpy.typing import DTypeLike

from ..blocks import SampleBlock
from .command_queue import CommandQueue
from ..errors import ConfigError, InstrumentError, SimulationError
from ..messages import OPERATING_KEYS, OperatingPoint

if TYPE_CHECKING:
    from ..sim_backend.rig import SimulatedRig

__all__ = ["Source", "Controllable", "RigSource", "SyntheticSource", "BenchSource", "bench_source", "operating_meta",
           "OPERATING_KEYS"]



@runtime_checkable
class Source(Protocol):
    """Where samples come from.  ``blocks`` ends when the source does or ``stop`` is set."""

    name: str
    channels: list[str]
    fs_hz: float

    def metadata(self) -> dict: ...  # the recording sidecar: rig, frequency_Hz, sample_rate_Hz, ...

    def blocks(self, stop: threading.Event | None = None) -> Iterator[SampleBlock]: ...

    def close(self) -> None: ...


@runtime_checkable
class Controllable(Protocol):
    """A source that drives the bench: commands take effect at the next block boundary."""

    def set_excitation(self, frequency_hz: float | None = None, current_pp_a: float | None = None,
                       offset_a: float | None = None) -> None: ...

    def set_output(self, on: bool) -> None: ...

    def set_waveform(self, current_a: np.ndarray, frequency_hz: float) -> None: ...


def operating_meta(frequency_hz: float, current_pp_a: float, offset_a: float, output_on: bool,
                   settling: bool = False, table: int = 0) -> dict[str, float]:
    """Block meta naming the operating point (:meth:`~hystbench.messages.OperatingPoint.to_meta`;
    ``settling`` and ``table``: see :class:`~hystbench.messages.OperatingPoint`)."""
    return OperatingPoint(float(frequency_hz), float(current_pp_a), float(offset_a), bool(output_on),
                          bool(settling), int(table)).to_meta()


def _counted(source: Any, command: Callable[[], None]) -> Callable[[], None]:
    """``command`` changes what the generator plays: once applied, the source's ``_tables`` count
    (the ``table`` of its blocks' meta) moves on."""
    def apply() -> None:
        command()
        source._tables += 1
    return apply


def _paced(blocks: Iterator[SampleBlock], fs_hz: float, pace: str, stop: threading.Event | None) -> Iterator[SampleBlock]:
    """Hold each block until real time has caught up with its last sample."""
    t0, i0 = time.monotonic(), None
    for b in blocks:
        if stop is not None and stop.is_set():
            return
        if pace == "realtime":
            i0 = b.first_index if i0 is None else i0
            wait = t0 + (b.end_index - i0) / fs_hz - time.monotonic()
            if wait > 0:
                if stop is not None:
                    if stop.wait(wait):
                        return
                else:
                    time.sleep(wait)
        yield b


#: The largest block a simulated source makes at once (10 s at 100 kS/s): a block is computed and
#: held whole, so a billion samples would never come (nor fit in memory).
MAX_BLOCK_SAMPLES = 1_000_000


class RigSource:
    """The simulated rig as a source; commands are queued and applied between blocks."""

    def __init__(self, rig: SimulatedRig, *, block_samples: int = 1000, pace: str = "realtime",
                 duration_s: float | None = None, dtype: DTypeLike = np.float32,
                 max_current_a: float | None = None) -> None:
        if pace not in ("max", "realtime"):
            raise ConfigError(f"pace must be 'max' or 'realtime', got {pace!r}")
        if not 1 <= block_samples <= MAX_BLOCK_SAMPLES:
            raise ConfigError(f"block_samples must be in [1, {MAX_BLOCK_SAMPLES:.0e}], got {block_samples}")
        self.rig = rig
        self.name = f"simulated rig {rig.name}"
        self.channels = list(rig.channels)
        self.fs_hz = rig.fs_hz
        self.block_samples, self.pace, self.duration_s = int(block_samples), pace, duration_s
        self.dtype = np.dtype(dtype)
        self._commands = CommandQueue(self.name, lambda: setattr(self.rig, "output_enabled", False))
        self._tables = 0  # changes of what the generator plays
        #: the peak coil current (|offset| + amplitude) no command may exceed; None: unchecked
        self.max_current_a = None if max_current_a is None else float(max_current_a)

    def metadata(self) -> dict:
        return self.rig.metadata()

    def _check_peak(self, what: str, peak_a: float) -> None:
        if self.max_current_a is not None and not peak_a <= self.max_current_a * (1 + 1e-9):
            raise ConfigError(f"{self.name}: refused {what}: the coil current it really drives peaks at {peak_a:.4g} A, "
                              f"beyond the bench's max_current_a = {self.max_current_a:g} A")

    def set_excitation(self, frequency_hz: float | None = None, current_pp_a: float | None = None,
                       offset_a: float | None = None) -> None:
        if frequency_hz is not None and not 0 < frequency_hz < self.fs_hz / 2:  # refuse now, not later
            raise ConfigError(f"frequency_hz {frequency_hz} must be in (0, {self.fs_hz / 2:g}) Hz")
        if current_pp_a is not None and not current_pp_a >= 0:
            raise ConfigError(f"current_pp_a must be >= 0, got {current_pp_a}")
        ipp = self.rig.current_pp_a if current_pp_a is None else current_pp_a
        off = self.rig.offset_a if offset_a is None else offset_a
        f = self.rig.frequency_hz if frequency_hz is None else frequency_hz
        if self.max_current_a is not None:  # the rig's physics: a flux-fed toroid draws far more than its command
            self._check_peak(f"{ipp:g} A-pp {off:+g} A at {f:g} Hz", self.rig.peak_current_a(f, ipp, off))
        self._commands.put(_counted(self, lambda: self.rig.set_excitation(frequency_hz, current_pp_a, offset_a)))

    def set_output(self, on: bool) -> None:
        """On: queued, applied between blocks.  Off: at once (:class:`CommandQueue`)."""
        if on:
            self._commands.put(lambda: setattr(self.rig, "output_enabled", True), output_on=True)
        else:
            self._commands.output_off()

    def set_waveform(self, current_a: np.ndarray, frequency_hz: float) -> None:
        table = np.array(current_a, dtype=float)
        if not 0 < frequency_hz < self.fs_hz / 2:
            raise ConfigError(f"{self.name}: refused a waveform at {frequency_hz} Hz: outside (0, {self.fs_hz / 2:g}) Hz")
        if table.size and self.max_current_a is not None:
            self._check_peak(f"a waveform of {table.size} points at {frequency_hz:g} Hz",
                             self.rig.peak_current_a(frequency_hz, waveform=table))
        self._commands.put(_counted(self, lambda: self.rig.set_waveform(table, frequency_hz)))


    def _raw(self, stop: threading.Event | None) -> Iterator[SampleBlock]:
        left = None if self.duration_s is None else int(round(self.duration_s * self.fs_hz))
        while left is None or left > 0:
            if stop is not None and stop.is_set():
                return
            self._commands.apply()
            n = self.block_samples if left is None else min(self.block_samples, left)
            b = self.rig.read(n)
            r = self.rig
            meta = operating_meta(r.frequency_hz, r.current_pp_a, r.offset_a, r.output_enabled, table=self._tables)
            yield SampleBlock(b.first_index, b.fs_hz, {k: v.astype(self.dtype, copy=False) for k, v in b.channels.items()},
                              flags=b.flags, gap_samples=b.gap_samples, meta=meta)
            if left is not None:
                left -= n

    def blocks(self, stop: threading.Event | None = None) -> Iterator[SampleBlock]:
        return _paced(self._raw(stop), self.fs_hz, self.pace, stop)

    def close(self) -> None:
        self._commands.close()


class SyntheticSource:
    """Sines with known delays, precomputed once and replayed from memory (no physics per block).

    The excitation is set to ``fs / P`` with P whole samples per period, and the buffer holds a
    whole number of periods and of blocks, so the replayed stream is continuous forever.  Flux
    lags current by ``flux_lag_s``, force lags flux by ``force_lag_s`` (with-magnet E-core shape).
    """

    #: the replayed buffer's length limit, per channel (4 float32 channels: 160 MB)
    MAX_BUFFER_SAMPLES = 10_000_000

    def __init__(self, *, fs_hz: float = 1e6, frequency_hz: float = 320.0, block_samples: int = 10_000,
                 channels: tuple[str, ...] = ("current_A", "force_N", "flux_Wb", "command_V"),
                 pace: str = "realtime", duration_s: float | None = None, dtype: DTypeLike = np.float32,
                 flux_lag_s: float = 10e-6, force_lag_s: float = 12e-6, noise: float = 1e-3, seed: int = 0,
                 rig: str = "ecore_pm", current_pp_a: float = 1.4) -> None:
        period = max(4, int(round(fs_hz / frequency_hz)))
        self.fs_hz, self.frequency_hz = float(fs_hz), float(fs_hz) / period
        self.block_samples, self.pace, self.duration_s = int(block_samples), pace, duration_s
        self.channels, self.rig, self.current_pp_a = list(channels), rig, float(current_pp_a)
        self.name = f"synthetic {self.frequency_hz:g} Hz at {self.fs_hz:g} S/s"
        length = period * self.block_samples // math.gcd(period, self.block_samples)
        while length < 4 * self.block_samples:
            length *= 2
        if length > self.MAX_BUFFER_SAMPLES:
            raise ConfigError(f"{self.name}: {period} samples per period in blocks of {self.block_samples} need a "
                              f"buffer of {length:.3g} samples per channel, more than {self.MAX_BUFFER_SAMPLES:.0e}; "
                              "lower fs_hz or block_samples, or raise frequency_hz")
        t = np.arange(length) / self.fs_hz
        w = 2 * np.pi * self.frequency_hz
        rng = np.random.default_rng(seed)
        amp = 0.5 * current_pp_a
        shapes = {"current_A": amp * np.sin(w * t), "flux_Wb": 5e-5 * np.sin(w * (t - flux_lag_s)),
                  "force_N": 175.0 + 45.0 * np.sin(w * (t - flux_lag_s - force_lag_s)),
                  "command_V": 2 * amp * np.sin(w * t),
                  "sense_V": -0.1 * np.cos(w * (t - flux_lag_s))}  # -turns dflux/dt, the presets' sign
        self._buf = {}
        for c in self.channels:
            x = shapes.get(c, np.sin(w * t))
            self._buf[c] = (x + noise * np.std(x) * rng.standard_normal(length)).astype(dtype)
        self._length = length

    def metadata(self) -> dict:
        return {"rig": self.rig, "frequency_Hz": self.frequency_hz, "sample_rate_Hz": self.fs_hz,
                "current_pp_A": self.current_pp_a, "source": self.name}

    def _raw(self, stop: threading.Event | None) -> Iterator[SampleBlock]:
        meta = operating_meta(self.frequency_hz, self.current_pp_a, 0.0, True)
        total = None if self.duration_s is None else int(round(self.duration_s * self.fs_hz))
        first = 0
        while total is None or first < total:
            if stop is not None and stop.is_set():
                return
            n = self.block_samples if total is None else min(self.block_samples, total - first)
            s = first % self._length
            yield SampleBlock(first, self.fs_hz, {c: x[s:s + n] for c, x in self._buf.items()}, meta=meta)
            first += n

    def blocks(self, stop: threading.Event | None = None) -> Iterator[SampleBlock]:
        return _paced(self._raw(stop), self.fs_hz, self.pace, stop)

    def close(self) -> None:
        pass


#: The shortest block the bench source hands on, in seconds of samples (unless a gap, a change of
#: operating point or a stalled stream ends it sooner).  The streams' runs come in pieces of a few
#: hundred samples; every block costs the pipeline's stages (publish, ring, estimate, record) their
#: per-block overhead, so they are gathered; the price is at most this much latency on the raw data.
MIN_BENCH_BLOCK_S = 0.02


class BenchSource:
    """The instruments through the drivers: the bench file's four sample streams, aligned on the
    common clock (``drivers.StreamAligner``; gaps come out exact, as ``GAP`` blocks).  Instruments
    with ``backend = "sim"`` are the emulators (``EmulatedBench``), started here behind their
    real protocols.  Commands go to the generator and the amplifier between blocks; the output is
    off until ``set_output(True)``."""

    def __init__(self, bench_file: str | None = None, *, rig: str | None = None,
                 duration_s: float | None = None, sim: Mapping[str, Any] | None = None,
                 excitation: tuple[float, float] | None = None, clear_faults: bool = False,
                 min_block_s: float = MIN_BENCH_BLOCK_S) -> None:
        """``min_block_s``: the shortest block handed on (see :data:`MIN_BENCH_BLOCK_S`); ``sim``
        replaces keys of the bench file's [sim] table (the emulated rig, its seed and
        effects; refused for hardware); ``excitation`` = (frequency Hz, current A-pp) is set on the
        generator once open (output off); ``clear_faults``: clear latched amplifier faults after
        opening (a restart after a fault; the output stays off)."""
        from dataclasses import replace

        from ..drivers.bench import Bench
        from ..drivers.protocols.bench_config import load_bench_config

        if not 0 <= min_block_s <= 1.0:  # before anything opens
            raise ConfigError(f"bench source: min_block_s must be in [0, 1] s, got {min_block_s}")
        cfg = load_bench_config(bench_file or None)
        self.emu = None
        self.bench = None
        if sim and not cfg.any_sim:
            raise ConfigError(f"{cfg.source}: {', '.join(sorted(sim))} apply to the emulated rig; this bench "
                              "file has hardware instruments only")
        if cfg.any_sim:
            from ..sim_backend.emulators.bench import EmulatedBench

            cfg = replace(cfg, sim={**cfg.sim, **dict(sim or {})})  # the tick sets latency_s too
            self.emu = EmulatedBench(cfg).start()
            cfg = cfg.resolved(self.emu.addresses)
        try:
            self.bench = Bench(cfg).open()
            if clear_faults:
                self.bench.clear_faults()
            self.gain = float(self.bench.budget.gain_a_per_v)
            if excitation is not None:
                frequency_hz, current_pp_a = excitation
                self.bench.generator.set_sine(frequency_hz, current_pp_a / self.gain, 0.0)
        except BaseException:
            self.close()
            raise
        self.fs_hz = cfg.fs_hz
        self.min_block_samples = max(1, int(round(min_block_s * self.fs_hz)))
        #: the longest a block's first samples wait for the rest (a stalled stream, a clock running
        #: behind real time): then what came goes on as it is
        self.gather_s = max(0.05, 2.5 * min_block_s)
        self.rig = self.emu.rig.name if self.emu is not None else (rig or "ecore_pm")  # hardware: say which
        self.max_current_a = cfg.current_limit_a  # the peak coil current a command may ask
        self.channels = ["current_A", "force_N", "flux_Wb", "command_V"]
        self.duration_s = duration_s
        #: what a command's effect may still take once the streams' readers have caught up with
        #: their transports: the samples still on their way (the instruments' buffers, the emulated
        #: rig's tick: ``BenchConfig.latency_s``) and 50 ms of the instruments' own response
        self.settle_s = max(0.1, 0.05 + cfg.latency_s)
        self._output = False
        self._tables = 0  # changes of what the generator plays
        self.name = f"bench {cfg.source}" + (" (emulated instruments)" if self.emu else "")
        self._commands = CommandQueue(self.name, self._output_off)

    def _output_off(self) -> None:
        self._output = False
        self.bench.safe_off()

    def metadata(self) -> dict:
        g = self.bench.generator.state
        base = self.emu.rig.metadata() if self.emu is not None else {}
        return {**base, "rig": self.rig, "frequency_Hz": float(g["frequency_hz"]), "sample_rate_Hz": self.fs_hz,
                "current_pp_A": float(g["amplitude_vpp"]) * self.gain, "source": self.name}

    def set_excitation(self, frequency_hz: float | None = None, current_pp_a: float | None = None,
                       offset_a: float | None = None) -> None:
        g = self.bench.generator
        self._commands.put(_counted(self, lambda: g.set_sine(
            g.state["frequency_hz"] if frequency_hz is None else frequency_hz,
            g.state["amplitude_vpp"] if current_pp_a is None else current_pp_a / self.gain,
            g.state["offset_v"] if offset_a is None else offset_a / self.gain)))

    def set_output(self, on: bool) -> None:
        """On: queued, applied between blocks.  Off: at once (:class:`CommandQueue`)."""
        def switch_on() -> None:
            self._output = False  # off first: a failing start_output leaves it off
            self.bench.start_output()
            self._output = True
        if on:
            self._commands.put(switch_on, output_on=True)
        else:
            self._commands.output_off()

    def set_waveform(self, current_a: np.ndarray, frequency_hz: float) -> None:
        volts = np.asarray(current_a, dtype=float) / self.gain
        self._commands.put(_counted(self, lambda: self.bench.generator.upload_waveform(volts, frequency_hz)))

    def blocks(self, stop: threading.Event | None = None) -> Iterator[SampleBlock]:
        """The bench's aligned blocks (``Bench.read_aligned``, the drivers' one acquisition loop),
        each with its operating point; commands are applied between blocks.

        A block is marked ``settling`` while it may hold samples made before the last command took
        effect, and for the instruments' response after.  Where the command takes effect is not
        where the reading stands (the cursor) but where the instruments' clock stood when it went
        out: the bench tells once the streams' readers have caught up with the transports
        (``Bench.commanded`` / ``Bench.change_index``, the one way every user of a bench learns
        it); until then everything is settling, however long a backlog (a starved reader, a full
        socket) takes to drain.  Nothing is dropped."""
        bench = self.bench
        bench.open_streams()
        left = None if self.duration_s is None else int(round(self.duration_s * self.fs_hz))
        settle_until = -1  # samples before this index may predate the last command, or ring after it
        pending = False  # a command went out and the bench does not know its change_index yet
        # settle_s counts from the live index at the command; change_index includes what was on its
        # way then (latency_samples): the rest is the instruments' own response
        lat = bench.latency_samples
        response = int(self.settle_s * self.fs_hz) - lat
        # The first block is the first one handed out, not the first turn after which the bench
        # knows where the streams start: a turn can learn that and still hand out nothing (a slow
        # stream's backlog ends before another's first sample, as on a loaded machine), and a
        # command applied after it would apply before the first block.
        started = False
        while (stop is None or not stop.is_set()) and (left is None or left > 0):
            cursor = bench.next_index if started else None
            # after the first sample (settling is counted from it), every sample the instruments
            # may still hold is marked settling
            if cursor is not None and self._commands.apply():
                bench.commanded()
                pending = True
            if pending and (change := bench.change_index()) is not None:
                # from the change, or from the cursor (plus what is on its way) if the reading is past it
                settle_until, pending = max(change, cursor + lat) + response, False
            limit = left  # a block ends where settling does, so each has one meta
            if not pending and cursor is not None and cursor < settle_until:
                limit = settle_until - cursor if limit is None else min(limit, settle_until - cursor)
            if cursor is None:  # the first block no longer than the minimum: commands queued before the
                # streams delivered (the switch-on) apply right after it, not after a whole backlog or burst
                limit = self.min_block_samples if limit is None else min(limit, self.min_block_samples)
            try:
                b = bench.read_aligned(limit, min_samples=self.min_block_samples, gather_s=self.gather_s)
            except InstrumentError as err:
                if self.emu is not None and self.emu.failure:  # the emulated rig's own cause, not its symptom
                    raise SimulationError(f"{err}; the cause: {self.emu.failure}") from err
                raise
            if b is None:
                continue
            started = True
            if left is not None:
                left -= b.n
            g = bench.generator.state
            settling = pending or b.first_index < settle_until
            meta = operating_meta(g["frequency_hz"], g["amplitude_vpp"] * self.gain, g["offset_v"] * self.gain,
                                  bool(g["output"]) and self._output, settling=settling, table=self._tables)
            yield SampleBlock(b.first_index, b.fs_hz, b.channels, flags=b.flags, gap_samples=b.gap_samples,
                              meta={**b.meta, **meta})

    def close(self) -> None:
        """Output off and everything closed (no queued command after the off; the drivers switch the
        output off first)."""
        if getattr(self, "_commands", None) is not None:
            self._commands.close()
        if getattr(self, "bench", None) is not None:
            self.bench.close()
        if self.emu is not None:
            self.emu.close()


def bench_source(bench_file: str | None = None, rig: str | None = None,
                 duration_s: float | None = None, **kw: Any) -> BenchSource:
    """The instruments of a bench file (default: the shipped ``config/bench.toml``) as a source
    (``kw``: see :class:`BenchSource`)."""
    return BenchSource(bench_file, rig=rig, duration_s=duration_s, **kw)
