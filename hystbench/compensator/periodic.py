"""One period of a periodic signal, uniformly sampled: the compensator's working representation.

Steady-state AC is what the bench runs and what a signal generator plays (one period, looped), so
models, inverses and the learning correction all work on period tables.  Here: spectral helpers
(derivative, resampling, an LTI response applied harmonic by harmonic) and the meter the closed
loop uses on live sample blocks -- the synchronous average at the generator's true frequency
aligned to the uploaded table, and the noise floor of that average.  The frequency and the average
are the analysis package's (:mod:`hystbench.analysis.periodic`), the same as offline.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Mapping

import numpy as np
from scipy import signal

from ..analysis.periodic import period_average
from ..physics.phase_delay_model import delay_periodic

__all__ = ["harmonics", "derivative", "resample", "apply_response", "denoise", "shift", "PeriodMeasurement",
           "measure_period", "fundamental_phase"]

Response = Callable[[np.ndarray], np.ndarray]


def harmonics(n: int) -> np.ndarray:
    """Harmonic numbers of the rfft bins of an n-point period."""
    return np.arange(n // 2 + 1)


def derivative(x: np.ndarray, frequency_hz: float) -> np.ndarray:
    """d/dt of one period (spectral; the Nyquist bin, which has no sign, is dropped)."""
    x = np.asarray(x, float)
    spec = np.fft.rfft(x) * (2j * np.pi * frequency_hz * harmonics(x.size))
    if x.size % 2 == 0:
        spec[-1] = 0.0
    return np.fft.irfft(spec, x.size)


def resample(x: np.ndarray, n: int) -> np.ndarray:
    """The same period on n points (band-limited, periodic)."""
    x = np.asarray(x, float)
    return x.copy() if x.size == n else signal.resample(x, n)


def apply_response(x: np.ndarray, frequency_hz: float, response: Response, *, inverse: bool = False,
                   max_harmonic: int | None = None) -> np.ndarray:
    """An LTI system ``response(f) -> H(j 2 pi f)`` applied to a period, harmonic by harmonic.

    ``inverse`` divides by H instead (the instrument's correction); ``max_harmonic`` keeps only
    harmonics up to it (the band where the division is trusted), dropping the rest."""
    x = np.asarray(x, float)
    spec = np.fft.rfft(x)
    k = harmonics(x.size)
    h = np.asarray(response(k * float(frequency_hz)), dtype=complex)
    spec = spec / h if inverse else spec * h
    if max_harmonic is not None:
        spec[k > max_harmonic] = 0.0
    return np.fft.irfft(spec, x.size)


def denoise(x: np.ndarray, noise_rms: float, *, threshold: float = 4.0, keep: int = 2) -> np.ndarray:
    """A period average with the harmonics that are indistinguishable from its noise set to zero.

    White noise of rms ``noise_rms`` per point puts sqrt(n) noise_rms (rms) in every rfft bin; bins
    below ``threshold`` times that are dropped (a Rayleigh bin exceeds 4x its rms with probability
    1e-7), the DC and the first ``keep`` harmonics always kept.  Without this a model's prediction
    carries the averaged current's noise near the load cell's resonance, amplified 40x there."""
    x = np.asarray(x, float)
    if not (np.isfinite(noise_rms) and noise_rms > 0):
        return x.copy()
    spec = np.fft.rfft(x)
    small = np.abs(spec) < threshold * np.sqrt(x.size) * noise_rms
    small[: keep + 1] = False
    spec[small] = 0.0
    return np.fft.irfft(spec, x.size)


def noise_floor_rms(x: np.ndarray) -> float:
    """The white-noise rms per point of a period average, read from the upper half of its spectrum
    (where a smooth loop has no harmonics): the median bin is sqrt(n ln 2) times it (Rayleigh).
    For channels whose noise the recording does not state (the flux)."""
    x = np.asarray(x, float)
    spec = np.abs(np.fft.rfft(x))[x.size // 4:]
    return float(np.median(spec) / np.sqrt(x.size * np.log(2.0))) if spec.size else 0.0


def shift(x: np.ndarray, delay_cycles: float) -> np.ndarray:
    """The period delayed by a fraction of a period (negative: advanced)."""
    return delay_periodic(np.asarray(x, float), float(delay_cycles))


def fundamental_phase(x: np.ndarray) -> complex:
    """The fundamental's complex amplitude of a period (phase reference: sample 0)."""
    return complex(np.fft.rfft(np.asarray(x, float))[1])


# --- the live meter --------------------------------------------------------------------------------
@dataclass(frozen=True)
class PeriodMeasurement:
    """Period averages of live channels, phase 0 = sample 0 of the uploaded table.

    ``alternating`` holds the periods averaged with alternating signs: every periodic component
    cancels and the noise stays exactly as the plain average has it, so its largest magnitude is
    the honest noise floor of the average (same record, same resampling)."""

    frequency_hz: float
    periods: int
    channels: dict[str, np.ndarray]
    alternating: dict[str, np.ndarray]

    def floor(self, name: str) -> float:
        """max |alternating average| of a channel: the averaged noise of this record length."""
        return float(np.max(np.abs(self.alternating[name])))


def measure_period(channels: Mapping[str, np.ndarray], fs_hz: float, frequency_hz: float, table: np.ndarray,
                   *, reference: str = "command_V", n_points: int = 1000) -> PeriodMeasurement:
    """Average every whole period of ``channels`` at ``frequency_hz`` and rotate the averages so
    that phase 0 is sample 0 of ``table`` (what was uploaded), found from the ``reference``
    channel's fundamental (the generator's output monitor)."""
    avg = period_average(channels, fs_hz, frequency_hz, n_points)
    if avg.periods < 2:  # the floor needs two periods of alternating sign
        raise ValueError(f"{np.size(channels[reference])} samples hold one period of {frequency_hz:g} Hz; need >= 2")
    tab = resample(np.asarray(table, float), n_points)
    ratio = fundamental_phase(avg.channels[reference]) / fundamental_phase(tab)
    lead = np.angle(ratio) / (2 * np.pi)  # the record started this many cycles into the table
    rot = {k: shift(v, lead) for k, v in avg.channels.items()}
    rot_alt = {k: shift(v, lead) for k, v in avg.alternating.items()}
    return PeriodMeasurement(float(frequency_hz), avg.periods, rot, rot_alt)
