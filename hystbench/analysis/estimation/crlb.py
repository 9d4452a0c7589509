"""Cramer-Rao lower bounds for the phase difference (and time delay) of two noisy sinusoids.

For a sinusoid of amplitude A in white Gaussian noise of variance sigma^2, sampled N times, the
per-sample signal-to-noise ratio is ``eta = A^2 / (2 sigma^2)`` and the variance of any unbiased
phase estimate is at least ``1 / (N eta)``.  This holds with amplitude, offset and frequency
unknown too, provided the phase is referenced to the record centre (the frequency then decouples
from the phase) and the record spans many periods; for records of a few periods the nuisance
parameters cost a few per cent more.  With independent noise on the two channels the bound on
the phase difference is the sum (Rife & Boorstyn 1974; Kay, *Fundamentals of Statistical Signal
Processing I*, Sec. 3.7)::

    var(dphi) >= 1 / (N eta_x) + 1 / (N eta_y)
    var(delay) >= var(dphi) / (2 pi k f)^2
"""

from __future__ import annotations

import numpy as np

__all__ = ["sine_snr", "phase_difference_crlb", "delay_crlb"]


def _positive(value, name: str, *, allow_inf: bool = False) -> np.ndarray:
    arr = np.asarray(value, dtype=np.float64)
    ok = (arr > 0) & (np.isfinite(arr) | (allow_inf & (arr == np.inf)))
    if not np.all(ok):
        raise ValueError(f"{name} must be {'> 0' if allow_inf else 'finite and > 0'}, got {value!r}")
    return arr


def sine_snr(amplitude: float | np.ndarray, noise_std: float | np.ndarray) -> np.ndarray:
    """Per-sample signal-to-noise ratio ``eta = A^2 / (2 sigma^2)`` of a sinusoid (linear).

    Parameters
    ----------
    amplitude : float or array_like
        Amplitude A of the sinusoid (signal units), > 0.
    noise_std : float or array_like
        Standard deviation sigma of the white noise (same units), > 0.

    Returns
    -------
    ndarray
        eta, dimensionless; ``10 log10(eta)`` is the SNR in dB.

    Examples
    --------
    >>> from hystbench.analysis.estimation import sine_snr
    >>> float(sine_snr(1.0, 0.125))
    32.0
    """
    amp = _positive(amplitude, "amplitude")
    std = _positive(noise_std, "noise_std")
    return (amp * amp / (2.0 * std * std))[()]


def phase_difference_crlb(n: int | np.ndarray, eta_x: float | np.ndarray, eta_y: float | np.ndarray) -> np.ndarray:
    """Lower bound on the variance of the phase difference of two noisy sinusoids (rad^2).

    ``1 / (N eta_x) + 1 / (N eta_y)``; the asymptotic bound, see the module docstring.

    Parameters
    ----------
    n : int or array_like
        Number of samples N in each record, >= 1.
    eta_x, eta_y : float or array_like
        Per-sample SNR of each channel at the harmonic considered, ``A^2 / (2 sigma^2)`` (see
        :func:`sine_snr`), > 0; ``inf`` for a noiseless channel.

    Returns
    -------
    ndarray
        Variance bound (rad^2); broadcast over the arguments.

    Raises
    ------
    ValueError
        If ``n`` is not a positive integer or an ``eta`` is not > 0.

    Examples
    --------
    >>> from hystbench.analysis.estimation import phase_difference_crlb
    >>> float(phase_difference_crlb(1000, 100.0, 100.0))
    2e-05
    """
    n_arr = np.asarray(n)
    if n_arr.dtype.kind not in "iu" or np.any(n_arr < 1):
        raise ValueError(f"n must be a positive integer number of samples, got {n!r}")
    ex = _positive(eta_x, "eta_x", allow_inf=True)
    ey = _positive(eta_y, "eta_y", allow_inf=True)
    return (1.0 / (n_arr * ex) + 1.0 / (n_arr * ey))[()]


def delay_crlb(
    n: int | np.ndarray,
    eta_x: float | np.ndarray,
    eta_y: float | np.ndarray,
    frequency_hz: float | np.ndarray,
    harmonic: int = 1,
) -> np.ndarray:
    """Lower bound on the variance of the time delay read at harmonic k (s^2).

    ``phase_difference_crlb(n, eta_x, eta_y) / (2 pi k frequency_hz)^2``.

    Parameters
    ----------
    n, eta_x, eta_y
        As :func:`phase_difference_crlb` (the etas at harmonic k).
    frequency_hz : float or array_like
        Fundamental frequency f (Hz), > 0.
    harmonic : int, optional
        Harmonic k at which the phase is read (default 1).

    Returns
    -------
    ndarray
        Variance bound (s^2).

    Examples
    --------
    >>> import numpy as np
    >>> from hystbench.analysis.estimation import delay_crlb
    >>> print(f"{np.sqrt(delay_crlb(1000, 100.0, 100.0, 320.0)) * 1e6:.3f} us")
    2.224 us
    """
    f = _positive(frequency_hz, "frequency_hz")
    if isinstance(harmonic, bool) or not isinstance(harmonic, (int, np.integer)) or harmonic < 1:
        raise ValueError(f"harmonic must be a positive integer, got {harmonic!r}")
    return (phase_difference_crlb(n, eta_x, eta_y) / (2.0 * np.pi * harmonic * f) ** 2)[()]
