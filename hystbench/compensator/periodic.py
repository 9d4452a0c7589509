"""One period of a periodic signal, uniformly sampled: the compensator's working representation.

Steady-state AC is what the bench runs and what a signal generator plays (one period, looped), so
models, inverses and the learning correction all work on period tables.  Here: spectral helpers
(derivative, resampling, an LTI response applied harmonic by harmonic) and the meter the closed
loop uses on live sample blocks -- frequency from the generator's own output, a synchronous
average aligned to the uploaded table, and the noise floor of that average.

The meter duplicates the offline ``acquisition.force_error.synchronous_average`` (cubic
resampling of every whole period at the estimated true frequency) on purpose: the compensator may
not import the acquisition package, and online it sees blocks, not recordings.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Mapping

import numpy as np
from scipy import signal
from scipy.interpolate import CubicSpline

from ..physics.phase_delay_model import delay_periodic

__all__ = ["harmonics", "derivative", "resample", "apply_response", "denoise", "shift", "PeriodMeasurement",
           "estimate_frequency", "measure_period", "fundamental_phase"]

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


def _harmonic_fit(x: np.ndarray, fs: float, f: float, k: int) -> complex:
    """Complex amplitude of the fundamental from a linear LS fit of DC + k harmonics at f."""
    t = (np.arange(x.size) - 0.5 * (x.size - 1)) / fs
    cols = [np.ones_like(t)]
    for h in range(1, k + 1):
        cols += [np.cos(2 * np.pi * h * f * t), np.sin(2 * np.pi * h * f * t)]
    coef = np.linalg.lstsq(np.stack(cols, axis=1), x, rcond=None)[0]
    return complex(coef[1], -coef[2])


def estimate_frequency(x: np.ndarray, fs: float, nominal_hz: float, *, harmonics_fitted: int = 5,
                       passes: int = 2) -> float:
    """True frequency of a periodic record near ``nominal_hz``: the fundamental's phase advance
    from the first to the second half of the record (generator and ADC clocks differ by ppm)."""
    x = np.asarray(x, float)
    half = x.size // 2
    f = float(nominal_hz)
    for _ in range(passes):
        a = _harmonic_fit(x[:half], fs, f, harmonics_fitted)
        b = _harmonic_fit(x[half:2 * half], fs, f, harmonics_fitted)
        if abs(a) == 0.0 or abs(b) == 0.0:
            return f
        dt = half / fs
        turns = f * dt  # expected whole and fractional cycles between the two centres
        dphi = np.angle(b / a) - 2 * np.pi * (turns - np.round(turns))
        dphi = (dphi + np.pi) % (2 * np.pi) - np.pi
        f += dphi / (2 * np.pi * dt)
    return f


def measure_period(channels: Mapping[str, np.ndarray], fs_hz: float, frequency_hz: float, table: np.ndarray,
                   *, reference: str = "command_V", n_points: int = 1000) -> PeriodMeasurement:
    """Average every whole period of ``channels`` at ``frequency_hz`` and rotate the averages so
    that phase 0 is sample 0 of ``table`` (what was uploaded), found from the ``reference``
    channel's fundamental (the generator's output monitor)."""
    x0 = np.asarray(channels[reference], float)
    t = np.arange(x0.size) / fs_hz
    periods = int(np.floor(t[-1] * frequency_hz + 1e-9))
    if periods < 2:
        raise ValueError(f"{x0.size} samples hold {periods} period(s) of {frequency_hz:g} Hz; need >= 2")
    even = periods - periods % 2
    phase = np.arange(n_points) / n_points
    when = (np.arange(periods)[:, None] + phase[None, :]) / frequency_hz
    signs = np.where(np.arange(even) % 2 == 0, 1.0, -1.0)[:, None]
    avg, alt = {}, {}
    for name, x in channels.items():
        grid = CubicSpline(t, np.asarray(x, float))(when)
        avg[name] = grid.mean(axis=0)
        alt[name] = (grid[:even] * signs).mean(axis=0)
    tab = resample(np.asarray(table, float), n_points)
    ratio = fundamental_phase(avg[reference]) / fundamental_phase(tab)
    lead = np.angle(ratio) / (2 * np.pi)  # the record started this many cycles into the table
    rot = {k: shift(v, lead) for k, v in avg.items()}
    rot_alt = {k: shift(v, lead) for k, v in alt.items()}
    return PeriodMeasurement(float(frequency_hz), periods, rot, rot_alt)
