"""What the compensator drives: the :class:`Actuation` protocol, and its simulated-rig implementation.

An actuation plays a current (a periodic table, or a sine), switches the output off, and hands
back sample blocks with at least ``force_N``, ``current_A`` and ``command_V`` (the generator's
output monitor: the meter finds the table's phase in it).  ``current_limit_a`` is the most it
may be asked for; an implementation refuses a table above it before anything is sent.

:class:`RigActuation` drives a :class:`~hystbench.sim_backend.rig.SimulatedRig` directly (imported
for type checking only, so this package does not load the simulator).

:class:`BenchActuation` drives a ``drivers.bench.Bench`` (likewise): the table goes to
the signal generator as an arbitrary waveform over SCPI, the samples come back through the four
instruments' streams -- real hardware, or the emulated instruments in front of a simulated rig.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Protocol, runtime_checkable

import numpy as np

from ..blocks import SampleBlock
from .errors import CompensatorError

if TYPE_CHECKING:
    from ..drivers.bench import Bench
    from ..sim_backend.rig import SimulatedRig

__all__ = ["Actuation", "RigActuation", "BenchActuation"]


@runtime_checkable
class Actuation(Protocol):
    """What the learning loop drives, so it runs alike on the simulated rig and on a bench (see above)."""

    name: str
    fs_hz: float
    current_limit_a: float

    def set_waveform(self, current_a: np.ndarray, frequency_hz: float) -> None: ...

    def set_sine(self, frequency_hz: float, current_pp_a: float, offset_a: float = 0.0) -> None: ...

    def output_off(self) -> None: ...

    def read(self, n: int) -> SampleBlock: ...


class RigActuation:
    """:class:`Actuation` on a simulated rig: its ``set_waveform``, ``set_excitation``,
    ``output_enabled`` and ``read``."""

    def __init__(self, rig: SimulatedRig, current_limit_a: float) -> None:
        if not current_limit_a > 0:
            raise CompensatorError(f"current_limit_a must be > 0, got {current_limit_a!r}")
        self.rig = rig
        self.name = f"simulated rig {getattr(rig, 'name', '?')} (direct, no instrument protocols)"
        self.fs_hz = float(rig.fs_hz)
        self.current_limit_a = float(current_limit_a)

    def _check(self, peak_a: float, what: str) -> None:
        if not np.isfinite(peak_a) or peak_a > self.current_limit_a * (1 + 1e-9):
            raise CompensatorError(f"{self.name}: refused {what}: peak {peak_a:.4g} A exceeds the "
                                   f"{self.current_limit_a:g} A limit")

    def set_waveform(self, current_a: np.ndarray, frequency_hz: float) -> None:
        table = np.asarray(current_a, dtype=float)
        self._check(float(np.max(np.abs(table))) if table.size else np.nan, f"a {table.size}-point waveform")
        self.rig.set_waveform(table, float(frequency_hz))
        self.rig.output_enabled = True

    def set_sine(self, frequency_hz: float, current_pp_a: float, offset_a: float = 0.0) -> None:
        self._check(abs(offset_a) + 0.5 * current_pp_a, f"a sine of {current_pp_a:g} A-pp at {offset_a:+g} A")
        self.rig.set_excitation(float(frequency_hz), float(current_pp_a), float(offset_a))
        self.rig.output_enabled = True

    def output_off(self) -> None:
        self.rig.output_enabled = False

    @property
    def output_on(self) -> bool:
        return bool(self.rig.output_enabled)

    def read(self, n: int) -> SampleBlock:
        return self.rig.read(int(n))


class BenchActuation:
    """:class:`Actuation` through the instrument drivers: ``set_waveform`` uploads ``current /
    gain`` volts to the generator (SCPI ``DATA:ARB``), ``set_sine`` sets its sine, ``output_off`` is
    the bench's safe-off (output off first), ``read`` acquires from the streams and refuses a gap.

    Consecutive reads are consecutive samples, but for a new table or sine: it is noted with the
    bench (``Bench.commanded``), and the next read starts at its ``Bench.change_index`` (the first
    live sample after the command plus what was still on its way then: the same place the
    pipeline's bench source marks its settling from), passing over the old excitation's samples,
    however long the caller computed or far behind the reading fell, so that, as on the rig
    directly, the next read starts at the change."""

    def __init__(self, bench: Bench, current_limit_a: float) -> None:
        if not current_limit_a > 0:
            raise CompensatorError(f"current_limit_a must be > 0, got {current_limit_a!r}")
        self.bench = bench
        self.gain_a_per_v = float(bench.budget.gain_a_per_v)
        self.fs_hz = float(bench.config.fs_hz)
        self.current_limit_a = min(float(current_limit_a), float(bench.budget.command_limit_a))
        self.name = f"bench {bench.config.source} through the drivers"
        self.output_on = False

    def _check(self, peak_a: float, what: str) -> None:
        if not np.isfinite(peak_a) or peak_a > self.current_limit_a * (1 + 1e-9):
            raise CompensatorError(f"{self.name}: refused {what}: peak {peak_a:.4g} A exceeds the "
                                   f"{self.current_limit_a:g} A limit")

    def _start(self) -> None:
        if not self.output_on:
            self.bench.start_output()
            self.output_on = True

    def set_waveform(self, current_a: np.ndarray, frequency_hz: float) -> None:
        table = np.asarray(current_a, dtype=float)
        self._check(float(np.max(np.abs(table))) if table.size else np.nan, f"a {table.size}-point waveform")
        self.bench.generator.upload_waveform(table / self.gain_a_per_v, float(frequency_hz))
        self._start()
        self.bench.commanded()

    def set_sine(self, frequency_hz: float, current_pp_a: float, offset_a: float = 0.0) -> None:
        self._check(abs(offset_a) + 0.5 * current_pp_a, f"a sine of {current_pp_a:g} A-pp at {offset_a:+g} A")
        self.bench.generator.set_sine(float(frequency_hz), current_pp_a / self.gain_a_per_v,
                                      offset_a / self.gain_a_per_v)
        self._start()
        self.bench.commanded()

    def output_off(self) -> None:
        self.bench.safe_off()
        self.output_on = False

    def read(self, n: int) -> SampleBlock:
        runs = self.bench.acquire(int(n) / self.fs_hz, since_command=True)
        if len(runs) != 1 or runs[0].n != int(n):
            raise CompensatorError(f"{self.name}: the streams had gaps while measuring: "
                                   f"{[(r.first_index, r.n, r.gap_samples) for r in runs]}")
        return runs[0]
