"""The simulated rig: signal generator -> current amplifier -> actuator -> instruments -> ADC.

It stands in for the bench when no hardware is attached: a real backend, not a test helper.  It
produces the recording format's channels in sample blocks, deterministic for a given seed and
independent of how the stream is cut into blocks, paced to real time or as fast as possible.
"""

from __future__ import annotations

import math
import time
from typing import Any, Iterator, Mapping

import numpy as np

from .. import __version__, jit
from ..blocks import SampleBlock, concatenate
from ..config import load_rig
from ..config.effects import resolve_effects
from ..errors import ConfigError
from .actuators import build_actuator
from .measurement import MeasurementChain

__all__ = ["SimulatedRig", "DEFAULT_FS_HZ", "KERNEL"]

DEFAULT_FS_HZ = 100_000.0
#: The generator's clock against the ADC's: they are independent, so the true excitation
#: frequency is off by this much (a typical crystal tolerance).  Estimators must not assume it.
DEFAULT_GENERATOR_CLOCK_PPM = 25.0
#: The largest peak coil current the rig simulates, A: beyond any bench amplifier, still far inside
#: the range where the iron model's numbers stay finite (they overflow somewhere above 1e12 A).
MAX_CURRENT_A = 1e4
#: Periods of an excitation simulated from rest to find the current it really drives (the toroid's
#: flux feedback reaches its steady loop within the first), and at most this many samples of them.
PEAK_PERIODS = 3
MAX_PEAK_SAMPLES = 1_000_000
#: The most samples the rig computes to settle before sample 0 (5 periods, at least 50 ms): a lower
#: frequency or a higher rate would take hours, or overflow the sample index.
MAX_WARMUP_SAMPLES = 10_000_000
#: None: the command sine is a compiled kernel when ``jit.enabled()``; a test sets True or False to
#: run one path (the numpy expression is the reference).
KERNEL: bool | None = None


class SimulatedRig:
    """One bench: a rig preset with its effects, excited by a sine (or one-period waveform)."""

    def __init__(self, rig: str | Mapping[str, Any] = "ecore_pm", *, fs_hz: float = DEFAULT_FS_HZ,
                 seed: int = 0, effects: Mapping[str, Mapping[str, Any] | bool] | None = None,
                 frequency_hz: float | None = None, current_pp_a: float | None = None,
                 offset_a: float = 0.0, generator_clock_ppm: float = DEFAULT_GENERATOR_CLOCK_PPM,
                 warmup_s: float | None = None, clock_offset_s: float = 0.0) -> None:
        self.preset = load_rig(rig)  # a name, a path or a dict: checked against the preset schema
        self.name = str(self.preset["name"])
        where = self.preset["_source"]
        if not (math.isfinite(fs_hz) and fs_hz > 0):
            raise ConfigError(f"{where}: the sample rate must be a finite number of Hz > 0, got {fs_hz}")
        self.fs_hz = float(fs_hz)
        self.seed = int(seed)
        if not math.isfinite(clock_offset_s):
            raise ConfigError(f"{where}: clock_offset_s must be a finite number of seconds, got {clock_offset_s}")
        #: Added to the sample clock of the instruments only (drift, mains): on a bench day several rigs
        #: share one charge amplifier and one mains, whose time runs on while the rigs are swapped.
        self.clock_offset_s = float(clock_offset_s)
        self.effects = resolve_effects(self.preset["effects"], effects, where, fs_hz=self.fs_hz)
        self.generator_clock_ppm = float(generator_clock_ppm)
        self.amplifier_gain_a_per_v = self.preset["amplifier"]["gain_a_per_v"]
        exc = self.preset["excitation"]
        self.actuator = build_actuator(self.preset, self.effects, self.fs_hz)
        self.channels = ["current_A"]
        if self.actuator.has_force:
            self.channels.append("force_N")
        if self.actuator.has_flux:
            self.channels += ["flux_Wb", "sense_V"]
        self.channels.append("command_V")
        self.sense_turns = self.preset["sense"]["turns"]
        self.chain = MeasurementChain(self.preset, self.effects, self.fs_hz, self.channels, self.seed)
        self.output_enabled = True
        self._waveform: np.ndarray | None = None
        self._cycle = 0.0  # generator phase at the next sample, in cycles [0, 1)
        # None (not 0, not any falsy value) means "the preset's": a 0 Hz request must be refused
        self.set_excitation(float(exc["frequency_hz"] if frequency_hz is None else frequency_hz),
                            float(exc["current_pp_a"] if current_pp_a is None else current_pp_a),
                            offset_a)
        if warmup_s is not None and not (math.isfinite(warmup_s) and warmup_s >= 0):
            raise ConfigError(f"{self.name}: warmup_s must be a finite number of seconds >= 0, got {warmup_s}")
        warm = warmup_s if warmup_s is not None else max(0.05, 5.0 / self.frequency_hz)
        if warm * self.fs_hz > MAX_WARMUP_SAMPLES:
            raise ConfigError(f"{self.name}: settling {warm:.4g} s (5 periods of {self.frequency_hz:g} Hz, at least "
                              f"50 ms) before sample 0 at fs {self.fs_hz:g} Hz is {warm * self.fs_hz:.3g} samples, "
                              f"more than {MAX_WARMUP_SAMPLES:.0e}: raise the frequency or lower the sample rate")
        self._next_index = -int(math.ceil(warm * self.fs_hz))
        while self._next_index < 0:  # settle hysteresis memory and filters before sample 0
            self._generate(min(-self._next_index, 50_000))

    # --- control (what the emulated generator and amplifier set) -------------------------------
    def set_excitation(self, frequency_hz: float | None = None, current_pp_a: float | None = None,
                       offset_a: float | None = None) -> None:
        """Sine current command; the phase runs on continuously across changes, as a generator's does."""
        if frequency_hz is not None and not 0 < frequency_hz < self.fs_hz / 2:  # also refuses NaN and inf
            raise ConfigError(f"{self.name}: excitation frequency {frequency_hz} Hz must be in "
                              f"(0, fs/2 = {self.fs_hz / 2} Hz)")
        if current_pp_a is not None and not (math.isfinite(current_pp_a) and current_pp_a >= 0):
            raise ConfigError(f"{self.name}: current_pp_a must be a finite number of A >= 0, got {current_pp_a}")
        if offset_a is not None and not math.isfinite(offset_a):
            raise ConfigError(f"{self.name}: offset_a must be a finite number of A, got {offset_a}")
        ipp = float(self.current_pp_a if current_pp_a is None else current_pp_a)
        offset = float(self.offset_a if offset_a is None else offset_a)
        if abs(offset) + ipp / 2 > MAX_CURRENT_A:
            raise ConfigError(f"{self.name}: peak current |offset_a| + current_pp_a/2 = {abs(offset) + ipp / 2:.4g} A "
                              f"is above the {MAX_CURRENT_A:g} A the simulated rig drives")
        if frequency_hz is not None:  # all checked: nothing changes on a refusal
            self.frequency_hz = float(frequency_hz)
        self.current_pp_a, self.offset_a = ipp, offset
        self._waveform = None
        self._dc_flux = self.actuator.dc_flux_wb(self.offset_a)
        self._tell_period()

    def set_waveform(self, current_a: np.ndarray, frequency_hz: float) -> None:
        """Arbitrary periodic current command: one period, uniformly sampled (the compensator's
        upload).  Played with periodic linear interpolation at ``frequency_hz``."""
        table = np.asarray(current_a, dtype=float)
        if table.ndim != 1 or table.size < 4 or not np.all(np.isfinite(table)):
            raise ConfigError("waveform must be a finite 1-D table of at least 4 samples")
        if np.max(np.abs(table)) > MAX_CURRENT_A:
            raise ConfigError(f"{self.name}: waveform peak {np.max(np.abs(table)):.4g} A is above the "
                              f"{MAX_CURRENT_A:g} A the simulated rig drives")
        self.set_excitation(frequency_hz=frequency_hz)
        self._waveform = table
        self._dc_flux = self.actuator.dc_flux_wb(float(table.mean()))
        self._tell_period()

    def _tell_period(self) -> None:
        if hasattr(self.actuator, "set_period"):
            self.actuator.set_period(self.fs_hz / self.generator_frequency_hz)
        if hasattr(self.actuator, "expect_current"):  # how the E-core solves its iron depends on it
            self.actuator.expect_current(*self._current_range())

    def _current_range(self) -> tuple[float, float]:
        """The lowest and highest coil current the excitation asks for (output on), after the
        amplifier's distortion when it is on."""
        if self._waveform is None:
            lo, hi = self.offset_a - 0.5 * self.current_pp_a, self.offset_a + 0.5 * self.current_pp_a
        else:
            lo, hi = float(self._waveform.min()), float(self._waveform.max())
        if "amplifier_distortion" not in self.effects:
            return lo, hi
        d = self.effects["amplifier_distortion"]
        i = np.linspace(lo, hi, 65)
        i = i + float(d["second"]) * i**2 + float(d["third"]) * i**3
        return float(i.min()), float(i.max())

    @property
    def generator_frequency_hz(self) -> float:
        """The true excitation frequency (nominal x generator clock error)."""
        return self.frequency_hz * (1.0 + 1e-6 * self.generator_clock_ppm)

    # --- the physics of one block ----------------------------------------------------------------
    def _command_current(self, c0: float, step: float, n: int) -> tuple[np.ndarray, np.ndarray]:
        """Commanded current and its time derivative at the generator phases ``c0 + step k`` (cycles),
        k = 0..n-1.  The sine is a compiled kernel when kernels run (the same numbers to a few ulp),
        else the numpy expression below, its reference."""
        w = 2 * np.pi * self.generator_frequency_hz
        if self._waveform is None:
            amp = 0.5 * self.current_pp_a
            if (jit.enabled() if KERNEL is None else KERNEL):
                from .kernels import sine_and_rate

                i_cmd, di_cmd = np.empty(n), np.empty(n)
                sine_and_rate(float(c0), float(step), self.offset_a, amp, amp * w, i_cmd, di_cmd)
                return i_cmd, di_cmd
            return self._sine_reference(c0 + step * np.arange(n), amp, w)
        cycles = c0 + step * np.arange(n)
        table = self._waveform
        size = table.size
        grid = np.arange(size + 1) / size
        wrapped = np.append(table, table[0])
        slope = np.diff(wrapped) * size * self.generator_frequency_hz
        frac = np.mod(cycles, 1.0)
        idx = np.minimum((frac * size).astype(int), size - 1)
        return np.interp(frac, grid, wrapped), slope[idx]

    def _sine_reference(self, cycles: np.ndarray, amp: float, w: float) -> tuple[np.ndarray, np.ndarray]:
        """The sine command in numpy: the reference the kernel is tested against."""
        return self.offset_a + amp * np.sin(2 * np.pi * cycles), amp * w * np.cos(2 * np.pi * cycles)

    def _coil_current(self, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Times, command voltage, and the amplifier's output current and its rate for the next n
        samples (from the generator's phase; nothing moves on)."""
        k0 = self._next_index
        t = np.arange(k0, k0 + n, dtype=float) / self.fs_hz  # whole numbers: exact, as (k0 + arange(n)) / fs
        step = self.generator_frequency_hz / self.fs_hz
        i_cmd, di_cmd = self._command_current(self._cycle, step, n)
        command_v = i_cmd / self.amplifier_gain_a_per_v
        if not self.output_enabled:
            i_cmd, di_cmd = np.zeros(n), np.zeros(n)
        current, dcurrent = i_cmd, di_cmd
        if "amplifier_distortion" in self.effects:  # i = i0 + k2 i0^2 + k3 i0^3 (per A, A^2)
            d = self.effects["amplifier_distortion"]
            k2, k3 = float(d["second"]), float(d["third"])
            current = i_cmd + k2 * i_cmd**2 + k3 * i_cmd**3
            dcurrent = di_cmd * (1 + 2 * k2 * i_cmd + 3 * k3 * i_cmd**2)
        return t, command_v, current, dcurrent

    def peak_current_a(self, frequency_hz: float | None = None, current_pp_a: float | None = None,
                       offset_a: float | None = None, waveform: np.ndarray | None = None) -> float:
        """The largest |coil current| an excitation (this rig's, with the arguments changed; a
        ``waveform``: one period of command) really drives with the output on: the command through
        the amplifier's distortion, or, where the actuator sets the current (the toroid's flux
        feedback, i = H l / N, which near saturation or at a high rate is far above the command:
        8.3 A for a nominal 1.71 A), what a new copy of the rig (warmed up at the preset's excitation,
        as any new rig is) draws over the first PEAK_PERIODS periods of the excitation, its switch-on
        transient included.  The rig itself is untouched: a command is checked with this before it is
        applied."""
        probe = SimulatedRig({k: v for k, v in self.preset.items() if k != "_source"} | {"effects": dict(self.effects)},
                             fs_hz=self.fs_hz, seed=self.seed)
        probe.set_excitation(self.frequency_hz, self.current_pp_a, self.offset_a)
        if waveform is None:
            probe.set_excitation(frequency_hz, current_pp_a, offset_a)
        else:
            probe.set_waveform(waveform, self.frequency_hz if frequency_hz is None else frequency_hz)
        probe.output_enabled = True
        n = min(int(math.ceil(PEAK_PERIODS * self.fs_hz / probe.frequency_hz)), MAX_PEAK_SAMPLES)
        t, _, current, dcurrent = probe._coil_current(n)
        if probe.actuator.sets_current:
            current = probe.actuator.step(t, current, dcurrent).current_a
        return float(np.max(np.abs(current)))

    def _generate(self, n: int) -> SampleBlock:
        """The next n samples.  A block the actuator refuses (SimulationError) changes nothing: the
        generator's phase and the sample index move on only once the block is made, so the same
        samples can be asked for again (the emulated bench does, with the output off)."""
        k0 = self._next_index
        t, command_v, current, dcurrent = self._coil_current(n)
        cycle = (self._cycle + self.generator_frequency_hz / self.fs_hz * n) % 1.0  # >= 0: exact, as np.mod
        out = self.actuator.step(t, current, dcurrent)
        truth = {"current_A": current if out.current_a is None else out.current_a, "command_V": command_v}
        if out.force_n is not None:
            truth["force_N"] = out.force_n
        if out.flux_wb is not None:
            truth["flux_Wb"] = out.flux_wb - self._dc_flux  # an integrator has no DC
            truth["sense_V"] = -self.sense_turns * out.dflux_dt
        # t + 0.0 is t: the shifted clock only costs a pass when a bench day shifts it
        channels, flags = self.chain.measure(t + self.clock_offset_s if self.clock_offset_s else t, truth)
        self._next_index, self._cycle = k0 + n, cycle
        return SampleBlock(k0, self.fs_hz, channels, flags=flags)

    # --- streaming ---------------------------------------------------------------------------------
    def read(self, n: int) -> SampleBlock:
        """The next ``n`` samples of every channel."""
        if not n > 0:
            raise ConfigError(f"{self.name}: the number of samples to read must be >= 1, got {n}")
        return self._generate(int(n))

    def skip(self, n: int) -> None:
        """Move the clock and the generator's phase on by ``n`` samples without simulating them.

        The rig's memory (iron, filters, delays) stays where the last sample left it, so what follows
        is a transient: a caller that skips settles the rig before it reads what it keeps (a replay
        of a bench day skips the long pauses between recordings when no slow effect spans them)."""
        if not n >= 0:
            raise ConfigError(f"{self.name}: the number of samples to skip must be >= 0, got {n}")
        self._cycle = (self._cycle + self.generator_frequency_hz / self.fs_hz * int(n)) % 1.0
        self._next_index += int(n)

    def blocks(self, block_size: int = 10_000, duration_s: float | None = None,
               pace: str = "max") -> Iterator[SampleBlock]:
        """Consecutive blocks; ``pace='realtime'`` sleeps so samples leave no faster than the ADC's."""
        if pace not in ("max", "realtime"):
            raise ConfigError(f"{self.name}: pace must be 'max' or 'realtime', got {pace!r}")
        remaining = None if duration_s is None else self.samples_in(duration_s)
        start_wall, start_index = time.monotonic(), self._next_index
        while remaining is None or remaining > 0:
            n = block_size if remaining is None else min(block_size, remaining)
            block = self.read(n)
            if remaining is not None:
                remaining -= n
            if pace == "realtime":
                due = start_wall + (block.end_index - start_index) / self.fs_hz
                time.sleep(max(0.0, due - time.monotonic()))
            yield block

    def record(self, duration_s: float, block_size: int = 50_000) -> SampleBlock:
        """``duration_s`` of samples as one block (as fast as possible)."""
        self.samples_in(duration_s)
        return concatenate(list(self.blocks(block_size, duration_s)))

    @property
    def next_index(self) -> int:
        """The index of the next sample the rig will deliver (0 is the first after its warm-up)."""
        return self._next_index

    def samples_in(self, duration_s: float) -> int:
        """The number of samples in ``duration_s``: at least one (0 s would be an empty recording)."""
        n = round(duration_s * self.fs_hz) if math.isfinite(duration_s) else 0
        if not (duration_s > 0 and n >= 1):
            raise ConfigError(f"{self.name}: the duration must be a finite number of seconds of at least one "
                              f"sample (1/{self.fs_hz:g} s), got {duration_s}")
        return int(n)

    def metadata(self) -> dict[str, Any]:
        """The recording sidecar for what this rig produces (recording-format keys plus extras)."""
        meta: dict[str, Any] = {
            "rig": self.name,
            "frequency_Hz": self.frequency_hz,
            "sample_rate_Hz": self.fs_hz,
            "current_pp_A": self.current_pp_a,
            "offset_A": self.offset_a,
            "generator_frequency_Hz": self.generator_frequency_hz,
            "source": f"hystbench {__version__} simulated rig",
            "seed": self.seed,
            "effects": {k: dict(v) for k, v in self.effects.items()},
        }
        if self.actuator.has_flux:
            meta["sense_turns"] = self.sense_turns
        return meta


