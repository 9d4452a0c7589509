"""The emulated bench: one SimulatedRig behind the four emulated instruments, on one sample clock.

A clock thread reads the rig block by block and hands every block to each instrument, which
streams its own channel: command_V from the generator, current_A from the amplifier's monitor,
force_N from the charge amplifier, flux_Wb from the integrator.  The generator's and amplifier's
settings set the rig's excitation, gain and output enable.

The sample clock is the emulator's only time.  Paced to real time, it never runs ahead of the wall
clock; when the machine is too busy for 100 kS/s it falls behind and simply goes on from where it
is, sample after sample: a short hiccup (up to ``CATCH_UP_S``) is caught up at once, a longer one
is not (a burst of seconds of frames would overflow the transports and starve the readers), so
no stream is ever dropped or stalled because the emulator was late; it only runs slower than real
time (``pacer.slipped_s`` says by how much).  Everything an emulator times (the amplifier's
watchdog, stream faults armed at a sample index) counts on this clock.

A tick's samples are made at once, so up to a tick of them is still on its way when a command
lands; no more (``BenchConfig.latency_s``): before making a tick, the clock waits until the last
one's samples are on the serial stream lines (``PtyStreamSink.wait_sent``; TCP's ``sendall`` and
the CAN bus take them at once), so an emulator's backlog, which a driver's reader cannot see, never
holds samples older than the newest tick.  With a reader that keeps up the wait is nil; a reader
short of CPU slows the clock rather than leaving old samples where the reader, finding its line
empty, would count them as on their way.

If the rig cannot make a block (a SimulationError names the rig, the operating point and why),
the clock does not stop, which the drivers would only report as a lost stream seconds later: the
amplifier trips (INTERLOCK, so its driver reports a latched fault at its next poll), the cause is
logged once and kept in ``failure``, and the same samples are made again with no current.
"""

from __future__ import annotations

import collections
import itertools
import os
import threading
import time
from typing import Any

from ...blocks import SampleBlock
from ...drivers.protocols.bench_config import BenchConfig, load_bench_config
from ...errors import ConfigError
from ..rig import SimulatedRig
from .charge_amplifier import ChargeAmplifierEmulator
from .common import PtyStreamSink, log
from .current_amplifier import CurrentAmplifierEmulator
from .flux_integrator import FluxIntegratorEmulator
from .signal_generator import SignalGeneratorEmulator

__all__ = ["EmulatedBench", "Pacer", "missing_channels"]

_channels = itertools.count()

#: The most the clock catches up at once after falling behind real time, in seconds of samples.
CATCH_UP_S = 0.02


class Pacer:
    """When the sample clock's next block is due: never ahead of real time; behind by up to
    ``catch_up_s`` it catches up at once, behind by more it goes on from where it is (the time lost
    is ``slipped_s``), so falling behind never turns into a burst of frames."""

    def __init__(self, fs_hz: float, start_s: float, start_index: int, catch_up_s: float = CATCH_UP_S) -> None:
        self.fs_hz, self.start_s, self.start_index, self.catch_up_s = fs_hz, start_s, start_index, catch_up_s
        self.late_s = 0.0  # how far behind real time the clock was at worst
        self.slipped_s = 0.0  # real time given up in all

    def wait_s(self, end_index: int, now_s: float) -> float:
        """Seconds to wait before producing the samples from ``end_index`` on, at time ``now_s``."""
        due = self.start_s + self.slipped_s + (end_index - self.start_index) / self.fs_hz
        lag = now_s - due
        self.late_s = max(self.late_s, lag)
        if lag > self.catch_up_s:  # go on from here at the sample rate: the same samples, later
            self.slipped_s += lag
        return max(0.0, -lag)


def missing_channels(rig: str) -> str:
    """What the emulated bench cannot stream of ``rig`` ('' if nothing): the force goes through its
    charge amplifier and the flux through its integrator, and a rig without one of them (the toroid
    has no force, a voice coil no flux) gave no sample ever, its stream "lost" 20 s later."""
    from ...config import load_rig
    from ..actuators import ACTUATORS

    actuator = ACTUATORS[load_rig(rig)["actuator"]]
    missing = [f"no {what} channel for the emulated bench's {instrument}" for what, instrument, has in (
        ("force", "charge amplifier", actuator.has_force), ("flux", "flux integrator", actuator.has_flux)) if not has]
    return f"{rig!r} has {' and '.join(missing)}" if missing else ""


class EmulatedBench:
    """``with EmulatedBench(config) as emu: emu.addresses`` -> where each instrument listens."""

    def __init__(self, config: BenchConfig | None = None) -> None:
        self.config = config or load_bench_config()
        sim = self.config.sim
        if missing := missing_channels(sim["rig"]):
            raise ConfigError(f"{self.config.source} [sim] rig: {missing}; simulate it directly (record --source sim, "
                              "a daemon's kind = \"sim\")")
        self.fs_hz = self.config.fs_hz
        self.block_samples = int(sim["block_samples"])
        self.pace = sim["pace"]
        # powered on with the amplifier disabled: the rig has seen no current (demagnetised iron)
        self.rig = SimulatedRig(sim["rig"], fs_hz=self.fs_hz, seed=int(sim["seed"]),
                                effects=dict(sim["effects"]), current_pp_a=0.0)
        self.rig.output_enabled = False
        self._rig_lock = threading.RLock()
        amp_settings = self.config.instruments["current_amplifier"].settings
        amp_opts = self.config.instruments["current_amplifier"].options
        integ = dict(self.config.instruments["flux_integrator"].options)
        if not self.config.instruments["flux_integrator"].is_sim:  # a real integrator's bus is not ours to join
            integ.update(interface="virtual", channel="", stream_channel="")
        channel = integ["channel"] or f"hystbench-emu-{os.getpid()}-{next(_channels)}"
        spf = int(sim["samples_per_frame"])
        self.generator = SignalGeneratorEmulator(on_change=self._update, samples_per_frame=spf)
        self.amplifier = CurrentAmplifierEmulator(unit=int(amp_opts["unit"]), on_change=self._update,
                                                  gain_a_per_v=self.rig.amplifier_gain_a_per_v,
                                                  current_limit_a=float(amp_settings.get("current_limit_a", 2.0)),
                                                  samples_per_frame=spf)
        self.charge_amp = ChargeAmplifierEmulator(fs_hz=self.fs_hz, samples_per_frame=spf,
                                                  load_cell_pc_per_n=float(sim["load_cell_pc_per_n"]))
        # the stream on a channel of its own (virtual bus): see the emulator's docstring
        stream_channel = integ.get("stream_channel") or (f"{channel}-stream" if integ["interface"] == "virtual" else "")
        try:
            self.integrator = FluxIntegratorEmulator(interface=integ["interface"], channel=channel,
                                                     node=int(integ["node"]), true_turns=self.rig.sense_turns,
                                                     stream_channel=stream_channel)
        except ConfigError as err:  # the three made before it listen on ports: closed, then said by file
            for emu in (self.generator, self.amplifier, self.charge_amp):
                emu.close()
            raise ConfigError(f"{self.config.source}: {err}") from err
        self.emulators = {"signal_generator": self.generator, "current_amplifier": self.amplifier,
                          "charge_amplifier": self.charge_amp, "flux_integrator": self.integrator}
        dig = self.config.digitiser
        if dig is not None and dig.is_sim:  # issue 15: one digitiser samples the four signals
            from .digitiser import DigitiserEmulator

            self.digitiser = DigitiserEmulator(self.fs_hz, {s: (int(ch[-1]), dig.scales.get(s, 1.0))
                                                            for s, ch in dig.channels.items()}, dialect=dig.dialect)
            self.emulators["digitiser"] = self.digitiser
        #: the serial stream lines, whose backlog each tick waits for (module docstring)
        self._serial_streams = [s for emu in self.emulators.values()
                                if isinstance(s := getattr(emu, "stream", None), PtyStreamSink)]
        self.next_index = 0  # the sample clock: first index of the next block (the rig starts at 0)
        #: the newest changes of the rig's settings: (first sample index generated with them, settings)
        self.changes: collections.deque[tuple[int, dict[str, Any]]] = collections.deque(maxlen=1000)
        self._update()
        self._stop = threading.Event()
        self._clock: threading.Thread | None = None
        self.blocks = 0
        self.pacer: Pacer | None = None  # paces the clock (pace = "realtime"); its late_s, slipped_s
        self.taps: list = []  # callables given every rig block (the truth), e.g. by tests
        #: why the rig last failed to make a block (rig, sample index, error), None if it never did
        self.failure: str | None = None

    @property
    def addresses(self) -> dict[str, Any]:
        """Where each instrument listens (the first line ``hystbench emulate`` prints)."""
        out: dict[str, Any] = {name: emu.addresses for name, emu in self.emulators.items()}
        out["fs_hz"] = self.fs_hz
        out["rig"] = self.rig.name
        out["seed"] = self.rig.seed
        return out

    # --- the rig follows the generator and the amplifier --------------------------------------------
    def _update(self) -> None:
        if not hasattr(self, "amplifier"):
            return  # construction: the amplifier is not there yet
        g, a = self.generator.state, self.amplifier
        with self._rig_lock:
            gain = a.gain_a_per_v
            self.rig.amplifier_gain_a_per_v = gain
            amp_a = float(g["amplitude_vpp"]) * gain
            off_a = float(g["offset_v"]) * gain
            if g["function"] == "ARB" and self.generator.arb_unit is not None:
                self.rig.set_waveform(self.generator.arb_unit * amp_a / 2 + off_a, float(g["frequency_hz"]))
            else:
                self.rig.set_excitation(float(g["frequency_hz"]), amp_a, off_a)
            self.rig.output_enabled = bool(g["output"]) and a.output_on
            now = {"output": self.rig.output_enabled, "function": g["function"],
                   "frequency_hz": float(g["frequency_hz"]), "amplitude_a": amp_a, "offset_a": off_a,
                   "uploads": self.generator.uploads}
            if not self.changes or self.changes[-1][1] != now:
                self.changes.append((self.next_index, now))

    # --- the sample clock ---------------------------------------------------------------------------------
    def start(self) -> "EmulatedBench":
        if self._clock is None:
            self._stop.clear()
            self._clock = threading.Thread(target=self._run, name="emu-clock", daemon=True)
            self._clock.start()
        return self

    @property
    def late_s(self) -> float:
        """How far the clock fell behind real time at worst (before going on from there)."""
        return self.pacer.late_s if self.pacer is not None else 0.0

    def _run(self) -> None:
        if self.pace == "realtime":
            self.pacer = Pacer(self.fs_hz, time.monotonic(), self.next_index)
        while not self._stop.is_set():
            try:
                block = self.tick()
            except Exception:  # the rig fails even with no current: nothing left to stream
                log.exception("emulated bench: the simulated rig %s cannot go on; the sample clock stops",
                              self.rig.name)
                return
            if self.pacer is not None and (wait := self.pacer.wait_s(block.end_index, time.monotonic())) > 0:
                self._stop.wait(wait)

    def tick(self) -> SampleBlock:
        """One block of the sample clock: the rig's next samples, to every tap and instrument (once
        the last block's samples are on the serial lines: the module docstring)."""
        for line in self._serial_streams:  # no lock held: commands go on meanwhile
            line.wait_sent()
        with self._rig_lock:
            try:
                block = self.rig.read(self.block_samples)
            except Exception as err:  # the rig's trouble must not stop the clock: output off, say why
                block = self._rig_failed(err)
            self.next_index = block.end_index
        for tap in list(self.taps):
            tap(block)
        for emu in self.emulators.values():
            emu.faults.clock_index = block.first_index
            try:
                emu.on_block(block)
            except Exception as err:  # one emulator's trouble must not stop the clock
                log.error("%s: block %d: %s", emu.kind, block.first_index, err)
        self.blocks += 1
        return block

    def _rig_failed(self, err: Exception) -> SampleBlock:
        """The rig refused the next block (it is left as it was): the amplifier trips, which switches
        the rig's output off, and the same samples are made again with no current.  Its driver
        sees a latched fault at the next poll (``heartbeat_s``) and the output goes off at once,
        where a silent stream would only be reported after its stall timeout and reconnection
        attempts, as "sample stream lost", with no word of why."""
        self.failure = f"simulated rig {self.rig.name}, sample {self.rig.next_index}: {type(err).__name__}: {err}"
        log.error("emulated bench: %s; the amplifier trips (INTERLOCK), output off", self.failure)
        self.amplifier.trip("INTERLOCK")  # on_change -> _update: the rig's output off (the lock is re-entrant)
        self.rig.output_enabled = False  # whatever the amplifier was doing
        return self.rig.read(self.block_samples)

    def close(self) -> None:
        self._stop.set()
        if self._clock is not None:
            self._clock.join(timeout=2.0)
            self._clock = None
        for emu in self.emulators.values():
            emu.close()

    def __enter__(self) -> "EmulatedBench":
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()
