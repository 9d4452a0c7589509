"""The paper's reference method: delay from the maximum of the covariance (Vrijsen et al. Eq. 3).

    sigma_XY(l) = 1/W sum_i (x_i - mean x)(y_{i+l} - mean y)

is evaluated for every integer lag ``l`` within one period of the excitation, and the lag of the
maximum is the delay in samples; the phase follows from the known sample time and excitation
frequency.  Faithful to the paper, it is quantised to one sample (error up to half a sample,
i.e. ``pi f / fs`` rad) and uses the nominal frequency; it is kept as the baseline the
least-squares estimator (:func:`.phase_delay`) is compared with.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.signal import fftconvolve

from . import _checks

__all__ = ["CovarianceDelay", "covariance_delay"]

_BLOCK = 1 << 16  # samples of x correlated at once (over all records), at least 4 periods


@dataclass(frozen=True)
class CovarianceDelay:
    """Result of :func:`covariance_delay` (arrays have the input's batch shape).

    Attributes
    ----------
    lag_samples : ndarray of int
        Lag of the covariance maximum (samples); positive: y lags x.
    delay_s : ndarray
        ``lag_samples / fs_hz`` (s).
    phase_rad : ndarray
        ``2 pi frequency_hz lag_samples / fs_hz`` (rad).
    covariance : ndarray
        The maximum covariance (product of the two signals' units).
    lags : ndarray of int
        The searched lags: one period, ``-(P // 2) .. P - P // 2 - 1`` with ``P = round(fs_hz / frequency_hz)``.
    """

    lag_samples: np.ndarray
    delay_s: np.ndarray
    phase_rad: np.ndarray
    covariance: np.ndarray
    lags: np.ndarray


def covariance_delay(x: np.ndarray, y: np.ndarray, fs_hz: float, frequency_hz: float, *,
                     axis: int = -1) -> CovarianceDelay:
    """Delay of ``y`` behind ``x`` as the lag of maximum covariance (the paper's Eq. 3).

    ``x`` is cut to a window of ``W = N - P + 1`` samples that leaves room for every lag in one
    period ``P = round(fs_hz / frequency_hz)`` (a lag range centred on zero); ``y`` slides along it.
    Every lag thus uses the same number of sample pairs, and the largest covariance wins (the
    first one on a tie).

    Parameters
    ----------
    x, y : array_like
        Reference and delayed channel, same shape.  For the E-core without magnet the paper
        compares force with *squared* flux; pass ``frequency_hz`` of the signals themselves (2f).
    fs_hz : float
        Sample rate (Hz).
    frequency_hz : float
        Frequency of the signals' common period (Hz), below fs/2.
    axis : int, optional
        Time axis (default -1).

    Returns
    -------
    CovarianceDelay
        Lag (samples), delay (s) and phase (rad) at the maximum.

    Raises
    ------
    ValueError
        Naming the parameter: bad ``fs_hz`` or ``frequency_hz`` (at or above fs/2), ``x``/``y`` shorter
        than two periods, NaN or inf in them, a flat channel, or ``y`` of another shape.

    Examples
    --------
    >>> import numpy as np
    >>> from hystbench.analysis.estimation import covariance_delay
    >>> fs_hz, f = 10_000.0, 320.0
    >>> t = np.arange(2000) / fs_hz
    >>> r = covariance_delay(np.sin(2 * np.pi * f * t), np.sin(2 * np.pi * f * (t - 2.4 / fs_hz)), fs_hz, f)
    >>> int(r.lag_samples), round(float(r.delay_s) * 1e6, 1)
    (2, 200.0)
    """
    fs_hz = _checks.check_fs(fs_hz)
    frequency_hz = _checks.check_freq(frequency_hz, fs_hz)
    xa = _checks.as_record(x, "x", axis)
    ya = _checks.as_record(y, "y", axis)
    _checks.check_same_shape(xa, ya)
    n = _checks.check_length(xa, "x", fs_hz, frequency_hz)
    _checks.check_not_flat(xa, "x")
    _checks.check_not_flat(ya, "y")

    period = max(int(round(fs_hz / frequency_hz)), 1)
    half = period // 2
    width = n - period + 1
    xw = xa[..., half : half + width]
    mean = xw.mean(axis=-1, keepdims=True)
    # cov[j] = 1/W sum_i xw[i] y[half + i + (j - half)]: the mean of y drops out as sum(xw) = 0.
    # The sum over i is taken in blocks of x, each correlated by FFT with the stretch of y it
    # meets (overlap-save): memory stays a few blocks however long the record.
    cov = np.zeros(xa.shape[:-1] + (period,))
    rows = max(1, int(np.prod(xa.shape[:-1])))
    step = max(_BLOCK // rows, 4 * period)
    for s in range(0, width, step):
        e = min(s + step, width)
        cov += fftconvolve(ya[..., s : e + period - 1], (xw[..., s:e] - mean)[..., ::-1], mode="valid", axes=-1)
    cov /= width
    lags = np.arange(period) - half
    j = np.argmax(cov, axis=-1)
    lag = lags[j]
    return CovarianceDelay(
        lag_samples=lag[()],
        delay_s=(lag / fs_hz)[()],
        phase_rad=(2.0 * np.pi * frequency_hz * lag / fs_hz)[()],
        covariance=np.take_along_axis(cov, j[..., None], axis=-1)[..., 0][()],
        lags=lags,
    )
