"""Least-squares sine fits (IEEE Std 1057/1241) and the phase delay between two channels.

A record is modelled as a DC offset plus chosen harmonics of one frequency ``f``::

    x(t) = offset + sum_k A_k cos(2 pi k f (t - t_ref) + phi_k) + noise,

with ``t`` the time of a sample from the first one and ``t_ref = (N - 1) / (2 fs)`` the record
centre.  Referencing the phase to the centre makes the phase and amplitude errors uncorrelated
with the frequency error, so the frequency can be estimated (four-parameter fit) at no cost in
phase accuracy.  Standard errors come from the least-squares covariance matrix scaled by the
residual noise variance; for white noise they reach the Cramer-Rao bound (:mod:`.crlb`).

Gross outliers (a glitch, a spike: samples many robust standard deviations off the fitted
waveform) are found per channel and left out of the fit (``outlier_sigmas``; see
:mod:`._outliers`); the result's ``excluded`` says which samples were.

Delays follow the design convention: positive means ``y`` lags ``x``.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from . import _checks, _lsq, _outliers
from ._outliers import OUTLIER_SIGMAS

__all__ = ["SineFit", "Harmonic", "PhaseDelay", "sine_fit", "phase_delay", "delay_between", "find_outliers",
           "gross_outliers", "OUTLIER_SIGMAS"]

_TWO_PI = 2.0 * np.pi


class Harmonic(NamedTuple):
    """One harmonic of a :class:`SineFit`: amplitude (signal units), phase (rad), their errors."""

    amplitude: np.ndarray
    amplitude_se: np.ndarray
    phase_rad: np.ndarray
    phase_se_rad: np.ndarray


@dataclass(frozen=True)
class SineFit:
    """Result of :func:`sine_fit`.

    Arrays have the batch shape of the input (the input's shape without its time axis); the
    per-harmonic ones carry one more, last, axis in the order of ``harmonics``.

    Attributes
    ----------
    frequency_hz, frequency_se_hz : ndarray
        Fundamental frequency and its standard error (Hz); the error is 0 when the frequency was
        given (``fit_freq=False``).
    harmonics : tuple of int
        Harmonic numbers k, ascending.
    amplitude, amplitude_se : ndarray, shape (..., K)
        Amplitude A_k of each harmonic and its standard error (signal units).
    phase_rad, phase_se_rad : ndarray, shape (..., K)
        Phase phi_k at the record centre, in (-pi, pi], and its standard error (rad).
    offset, offset_se : ndarray
        DC offset and its standard error (signal units).
    noise_std : ndarray
        Residual noise standard deviation (signal units), from the residual sum of squares over
        the degrees of freedom.
    t_ref_s : float
        Time of the phase reference, the record centre, after the first sample (s).
    n_samples : int
        Record length N.
    iterations : ndarray of int
        Gauss-Newton iterations used (1 for a fit at a given frequency).
    converged : ndarray of bool
        False if ``max_iter`` ran out before the frequency step fell below ``tol``.
    excluded : ndarray of bool, shape (..., N)
        Samples left out of the fit (outliers found, or excluded by the caller), time last.
    """

    frequency_hz: np.ndarray
    frequency_se_hz: np.ndarray
    harmonics: tuple[int, ...]
    amplitude: np.ndarray
    amplitude_se: np.ndarray
    phase_rad: np.ndarray
    phase_se_rad: np.ndarray
    offset: np.ndarray
    offset_se: np.ndarray
    noise_std: np.ndarray
    t_ref_s: float
    n_samples: int
    iterations: np.ndarray
    converged: np.ndarray
    excluded: np.ndarray

    @property
    def outliers(self) -> np.ndarray:
        """Indices of the samples left out of a single record's fit (ascending)."""
        if self.excluded.ndim != 1:
            raise ValueError("outliers: the fit is batched; use excluded (a mask per record)")
        return np.flatnonzero(self.excluded)

    def component(self, k: int) -> Harmonic:
        """Amplitude, phase and their standard errors of harmonic ``k``."""
        if k not in self.harmonics:
            raise ValueError(f"harmonic {k!r} was not fitted; fitted: {self.harmonics}")
        j = self.harmonics.index(k)
        return Harmonic(
            self.amplitude[..., j], self.amplitude_se[..., j], self.phase_rad[..., j], self.phase_se_rad[..., j]
        )


@dataclass(frozen=True)
class PhaseDelay:
    """Result of :func:`phase_delay`: how far ``y`` lags ``x`` at one harmonic.

    Attributes
    ----------
    harmonic : int
        The harmonic k at which the delay is read.
    phase_rad, phase_se_rad : ndarray
        Phase of x minus phase of y at harmonic k, wrapped to (-pi, pi], and its standard error
        (rad).  Positive: y lags x.
    delay_s, delay_se_s : ndarray
        Equivalent time delay ``phase_rad / (2 pi k frequency_hz)`` and its standard error (s).
    frequency_hz, frequency_se_hz : ndarray
        The fundamental frequency shared by both fits and its standard error (Hz).
    x, y : SineFit
        The two channels' fits (same frequency).
    """

    harmonic: int
    phase_rad: np.ndarray
    phase_se_rad: np.ndarray
    delay_s: np.ndarray
    delay_se_s: np.ndarray
    frequency_hz: np.ndarray
    frequency_se_hz: np.ndarray
    x: SineFit
    y: SineFit


def _exclusions(exclude, arrays, names, axis) -> np.ndarray | None:
    """The caller's masks of samples to leave out, as (B, C, N) bool (None: none)."""
    if exclude is None:
        return None
    if len(exclude) != len(arrays):
        raise ValueError(f"exclude must give one mask (or None) per channel, {len(arrays)}; got {len(exclude)}")
    out = []
    for m, arr, name in zip(exclude, arrays, names):
        if m is None:
            out.append(np.zeros(arr.shape, dtype=bool))
            continue
        m = np.asarray(m)
        if m.dtype != bool:
            raise ValueError(f"exclude for {name} must be a boolean mask, got dtype {m.dtype}")
        try:
            m = np.moveaxis(m, axis, -1)
        except np.exceptions.AxisError as err:
            raise ValueError(f"exclude for {name} has shape {m.shape}, {name} {arr.shape}") from err
        if m.shape != arr.shape:
            raise ValueError(f"exclude for {name} has shape {m.shape} (time last), {name} {arr.shape}")
        out.append(m)
    mask = np.stack([m.reshape(-1, m.shape[-1]) for m in out], axis=1)
    return mask if mask.any() else None


def _prepare(records, names, fs_hz, frequency_hz, harmonics, fit_freq, search_ppm, max_iter, tol, axis, exclude,
             outlier_sigmas):
    """Validate; return (B, C, N) data, batch shape, start frequencies, fs_hz, harmonics, tol, the
    caller's exclusions and the first fit's mask (both (B, C, N) or None) and the threshold."""
    fs_hz = _checks.check_fs(fs_hz)
    ks = _checks.check_harmonics(harmonics)
    if frequency_hz is not None:
        frequency_hz = _checks.check_freq(frequency_hz, fs_hz, ks[-1])
    if isinstance(max_iter, bool) or not isinstance(max_iter, (int, np.integer)) or max_iter < 1:
        raise ValueError(f"max_iter must be a positive integer, got {max_iter!r}")
    search_ppm = _checks.check_nonnegative(search_ppm, "search_ppm", allow_zero=True)
    tol = _checks.check_nonnegative(tol, "tol")
    if outlier_sigmas is not None:
        outlier_sigmas = _checks.check_nonnegative(outlier_sigmas, "outlier_sigmas")
    if frequency_hz is None and not fit_freq:
        raise ValueError("frequency_hz must be given when fit_freq is False")
    arrays = [_checks.as_record(r, name, axis) for r, name in zip(records, names)]
    for other in arrays[1:]:
        _checks.check_same_shape(arrays[0], other)
    n_params = len(arrays) * (1 + 2 * len(ks)) + int(fit_freq)
    if frequency_hz is not None:
        for arr, name in zip(arrays, names):
            _checks.check_length(arr, name, fs_hz, frequency_hz, n_params)
    for arr, name in zip(arrays, names):
        _checks.check_not_flat(arr, name)
    batch = arrays[0].shape[:-1]
    data = np.stack([a.reshape(-1, a.shape[-1]) for a in arrays], axis=1)  # (B, C, N)
    excluded = _exclusions(exclude, arrays, names, axis)
    mask = _outliers.initial_mask(data, excluded, outlier_sigmas)
    fill = None  # for the start frequency's search a left-out sample takes its channel's median
    if mask is not None and (frequency_hz is None or fit_freq):
        fill = _outliers.row_median(data)[..., 0]
    if frequency_hz is None:
        clean = data if mask is None else np.where(mask, fill[..., None], data)
        f0 = _lsq.fft_peak_freq(clean, fs_hz) / ks[0]
        f_max = float(np.max(f0))
        if ks[-1] * f_max >= fs_hz / 2.0:
            raise ValueError(f"harmonics: {ks[-1]} x the estimated {f_max:g} Hz is above fs/2 = {fs_hz / 2:g} Hz")
        for arr, name in zip(arrays, names):
            _checks.check_length(arr, name, fs_hz, float(np.min(f0)), n_params)
    elif fit_freq:
        f0 = _lsq.grid_start(data, fs_hz, frequency_hz, ks, 1e-6 * search_ppm * frequency_hz, mask, fill)
    else:
        f0 = np.full(data.shape[0], frequency_hz)
    return data, batch, f0, fs_hz, ks, tol, excluded, mask, outlier_sigmas


def _solve(records, names, fs_hz, frequency_hz, harmonics, fit_freq, search_ppm, max_iter, tol, axis, exclude,
           outlier_sigmas):
    """Validate, fit (leaving out outliers and exclusions); (solution, mask, data, batch, fs_hz, ks)."""
    data, batch, f0, fs_hz, ks, tol, excluded, mask, sigmas = _prepare(
        records, names, fs_hz, frequency_hz, harmonics, fit_freq, search_ppm, max_iter, tol, axis, exclude,
        outlier_sigmas)
    sol, mask = _outliers.robust_solve(data, fs_hz, f0, ks, fit_freq=fit_freq, max_iter=int(max_iter), tol=tol,
                                       exclude=excluded, mask=mask, sigmas=sigmas, names=tuple(names))
    if mask is None:
        mask = np.zeros(data.shape, dtype=bool)
    return sol, mask, data, batch, fs_hz, ks


def _channel_fit(sol: _lsq.Solution, c: int, ks, fs_hz, n, batch, fit_freq, mask) -> SineFit:
    p = 1 + 2 * len(ks)
    coef = sol.coef[:, c]
    cov = sol.cov[:, c * p : (c + 1) * p, c * p : (c + 1) * p]
    a, s = coef[:, 1::2], coef[:, 2::2]
    amp = np.hypot(a, s)
    phase = np.arctan2(-s, a)
    va, vs = cov[:, 1::2, 1::2].diagonal(axis1=-2, axis2=-1), cov[:, 2::2, 2::2].diagonal(axis1=-2, axis2=-1)
    vas = cov[:, 1::2, 2::2].diagonal(axis1=-2, axis2=-1)
    with np.errstate(divide="ignore", invalid="ignore"):
        amp_se = np.sqrt(np.maximum(a * a * va + s * s * vs + 2 * a * s * vas, 0.0)) / amp
        phase_se = np.sqrt(np.maximum(s * s * va + a * a * vs - 2 * a * s * vas, 0.0)) / (amp * amp)
    freq_se = np.sqrt(sol.cov[:, -1, -1]) if fit_freq else np.zeros_like(sol.freq)

    def shaped(v, per_k=False):
        return v.reshape(batch + ((len(ks),) if per_k else ()))[()]

    return SineFit(
        frequency_hz=shaped(sol.freq),
        frequency_se_hz=shaped(freq_se),
        harmonics=tuple(ks),
        amplitude=shaped(amp, True),
        amplitude_se=shaped(amp_se, True),
        phase_rad=shaped(phase, True),
        phase_se_rad=shaped(phase_se, True),
        offset=shaped(coef[:, 0]),
        offset_se=shaped(np.sqrt(cov[:, 0, 0])),
        noise_std=shaped(np.sqrt(sol.sigma2[:, c])),
        t_ref_s=(n - 1) / (2.0 * fs_hz),
        n_samples=n,
        iterations=shaped(sol.iterations),
        converged=shaped(sol.converged),
        excluded=mask[:, c].reshape(batch + (n,)),
    )


def sine_fit(
    x: np.ndarray,
    fs_hz: float,
    frequency_hz: float | None,
    *,
    harmonics: int | Iterable[int] = 1,
    fit_freq: bool = True,
    search_ppm: float = 200.0,
    axis: int = -1,
    max_iter: int = 50,
    tol: float = 1e-10,
    exclude: np.ndarray | None = None,
    outlier_sigmas: float | None = OUTLIER_SIGMAS,
) -> SineFit:
    """Least-squares fit of a DC offset and harmonics of one frequency to a record.

    With ``fit_freq=False`` this is the linear three-parameter fit of IEEE Std 1057 (or its
    multi-harmonic extension) at the given frequency; with ``fit_freq=True`` (default) the
    frequency is estimated too (four-parameter fit), by Gauss-Newton from ``frequency_hz``.

    Parameters
    ----------
    x : array_like
        Samples (signal units).  N-D input is fitted record by record along ``axis``.
    fs_hz : float
        Sample rate (Hz).
    frequency_hz : float or None
        Nominal fundamental frequency (Hz), or the exact one when ``fit_freq`` is False.  None
        starts from the interpolated peak of the spectrum, taken to be the lowest harmonic.
    harmonics : int or iterable of int, optional
        Harmonics k of ``frequency_hz`` to fit (default 1; e.g. ``(2,)`` for an E-core's force
        without magnet, ``(1, 2, 3)`` for a distorted sine).  All must lie below fs/2.
    fit_freq : bool, optional
        Estimate the frequency (default True).  Leave it on when the sampling and generator
        clocks are independent: a 30 ppm error over 200 periods already moves the phase at the
        record ends by 0.04 rad.
    search_ppm : float, optional
        How far (ppm) the true frequency may be from ``frequency_hz`` (default 200; generator and
        sampling clocks differ by tens of ppm).  Gauss-Newton converges from within about half a
        DFT bin ``fs / (k N)`` (k the highest harmonic); for records so long that the window
        is wider, the start is the best point of a quarter-bin grid over it.
    axis : int, optional
        Time axis of ``x`` (default -1).
    max_iter : int, optional
        Iteration limit of the frequency search (default 50).
    tol : float, optional
        Stop when the last frequency step moves the phase of the highest harmonic at the record
        ends by less than this (rad, default 1e-10), or is below 1e-6 of the frequency's
        standard error.
    exclude : array_like of bool, optional
        Samples to leave out of the fit whatever their values (same shape as ``x``).
    outlier_sigmas : float or None, optional
        Leave out samples whose residual is more than this many robust standard deviations (1.4826
        x the median absolute deviation of the residuals) off, refitting until the set settles
        (default 9: Gaussian noise never trips it); None keeps every sample.

    Returns
    -------
    SineFit
        Frequency, amplitudes, phases at the record centre, offset, their standard errors, and
        the samples left out (``excluded``, ``outliers``).

    Raises
    ------
    ValueError
        Naming the parameter: ``fs_hz`` not finite and positive; ``frequency_hz`` (times the highest
        harmonic) at or above fs/2; ``x`` shorter than two periods, containing NaN or inf, or
        flat; bad ``harmonics``, ``max_iter`` or ``tol``.

    Examples
    --------
    >>> import numpy as np
    >>> from hystbench.analysis.estimation import sine_fit
    >>> fs_hz, f = 10_000.0, 320.01
    >>> t = np.arange(2000) / fs_hz
    >>> x = 0.5 + 2.0 * np.cos(2 * np.pi * f * (t - t[-1] / 2) + 0.3)
    >>> fit = sine_fit(x, fs_hz, 320.0)
    >>> print(f"{fit.frequency_hz:.4f} Hz  A={fit.amplitude[0]:.6f}  phi={fit.phase_rad[0]:.6f}  dc={fit.offset:.6f}")
    320.0100 Hz  A=2.000000  phi=0.300000  dc=0.500000
    """
    sol, mask, data, batch, fs_hz, ks = _solve((x,), ("x",), fs_hz, frequency_hz, harmonics, fit_freq, search_ppm,
                                               max_iter, tol, axis, None if exclude is None else (exclude,),
                                               outlier_sigmas)
    return _channel_fit(sol, 0, ks, fs_hz, data.shape[-1], batch, fit_freq, mask)


def phase_delay(
    x: np.ndarray,
    y: np.ndarray,
    fs_hz: float,
    frequency_hz: float | None,
    *,
    harmonic: int = 1,
    harmonics: int | Iterable[int] | None = None,
    fit_freq: bool = True,
    search_ppm: float = 200.0,
    axis: int = -1,
    max_iter: int = 50,
    tol: float = 1e-10,
    exclude: tuple[np.ndarray | None, np.ndarray | None] | None = None,
    outlier_sigmas: float | None = OUTLIER_SIGMAS,
) -> PhaseDelay:
    """Delay of ``y`` behind ``x`` at one harmonic, from a joint least-squares sine fit.

    Both channels are fitted with one common frequency (they are sampled by one clock and
    excited by one generator).  The frequency is estimated jointly: the fit maximises the
    Gaussian likelihood with an unknown noise variance per channel, i.e. minimises
    ``log S_x + log S_y`` (S the residual sums of squares), so each channel weighs in with its
    own signal-to-noise ratio and the cleaner one dominates without having to be chosen.  As the
    phases are referenced to the record centre the frequency error barely touches the phase
    difference, so the estimate reaches the bound of :func:`.phase_difference_crlb`.

    Parameters
    ----------
    x, y : array_like
        Reference and delayed channel, same shape (signal units, may differ between channels).
    fs_hz : float
        Sample rate (Hz).
    frequency_hz : float or None
        Fundamental frequency, start of the search (Hz); see :func:`sine_fit`.
    harmonic : int, optional
        Harmonic k at which the delay is read (default 1; 2 for force against squared flux).
    harmonics : int or iterable of int, optional
        Harmonics fitted in both channels (default: ``harmonic`` only); must include ``harmonic``.
    fit_freq, search_ppm, axis, max_iter, tol, outlier_sigmas
        As in :func:`sine_fit`; outliers are found in each channel.
    exclude : (mask or None, mask or None), optional
        Samples of x and of y to leave out of the fit, as in :func:`sine_fit`.

    Returns
    -------
    PhaseDelay
        Phase (rad) and time delay (s) of y behind x with standard errors, and both fits.
        The time delay is the phase over ``2 pi k f``, so it is known modulo ``1 / (k f)``.

    Raises
    ------
    ValueError
        As :func:`sine_fit`, naming ``x`` or ``y``; also ``y`` of another shape than ``x`` and
        a ``harmonic`` missing from ``harmonics``.

    Examples
    --------
    >>> import numpy as np
    >>> from hystbench.analysis.estimation import phase_delay
    >>> fs_hz, f, d = 10_000.0, 320.0, 123.4e-6
    >>> t = np.arange(3000) / fs_hz
    >>> x = np.sin(2 * np.pi * f * t)
    >>> y = 3.0 * np.sin(2 * np.pi * f * (t - d)) + 1.0
    >>> r = phase_delay(x, y, fs_hz, 320.0)
    >>> print(f"{r.delay_s * 1e6:.4f} us, {np.degrees(r.phase_rad):.4f} deg")
    123.4000 us, 14.2157 deg
    """
    if isinstance(harmonic, bool) or not isinstance(harmonic, (int, np.integer)) or harmonic < 1:
        raise ValueError(f"harmonic must be a positive integer, got {harmonic!r}")
    ks = _checks.check_harmonics(harmonic if harmonics is None else harmonics)
    if harmonic not in ks:
        raise ValueError(f"harmonic {harmonic} is not among the fitted harmonics {ks}")
    sol, mask, data, batch, fs_hz, ks = _solve((x, y), ("x", "y"), fs_hz, frequency_hz, ks, fit_freq, search_ppm,
                                               max_iter, tol, axis, exclude, outlier_sigmas)
    n = data.shape[-1]
    fit_x = _channel_fit(sol, 0, ks, fs_hz, n, batch, fit_freq, mask)
    fit_y = _channel_fit(sol, 1, ks, fs_hz, n, batch, fit_freq, mask)

    # gradient of the phase difference with respect to (cos, sin) coefficients of both channels
    p = 1 + 2 * len(ks)
    j = ks.index(int(harmonic))
    ia, is_ = 1 + 2 * j, 2 + 2 * j
    grad = np.zeros(sol.cov.shape[:-1])
    for c, sign in ((0, 1.0), (1, -1.0)):
        a, s = sol.coef[:, c, ia], sol.coef[:, c, is_]
        a2 = a * a + s * s
        grad[:, c * p + ia] = sign * s / a2  # d phi / d a  (phi = atan2(-s, a))
        grad[:, c * p + is_] = -sign * a / a2
    phi_x = np.arctan2(-sol.coef[:, 0, is_], sol.coef[:, 0, ia])
    phi_y = np.arctan2(-sol.coef[:, 1, is_], sol.coef[:, 1, ia])
    dphi = np.angle(np.exp(1j * (phi_x - phi_y)))
    dphi = np.where(dphi <= -np.pi, dphi + _TWO_PI, dphi)
    var_phi = np.einsum("bi,bij,bj->b", grad, sol.cov, grad)
    omega = _TWO_PI * harmonic * sol.freq
    delay = dphi / omega
    grad_d = grad / omega[:, None]
    if fit_freq:
        grad_d[:, -1] = -delay / sol.freq  # d delay / d f
    var_d = np.einsum("bi,bij,bj->b", grad_d, sol.cov, grad_d)

    def shaped(v):
        return v.reshape(batch)[()]

    return PhaseDelay(
        harmonic=int(harmonic),
        phase_rad=shaped(dphi),
        phase_se_rad=shaped(np.sqrt(np.maximum(var_phi, 0.0))),
        delay_s=shaped(delay),
        delay_se_s=shaped(np.sqrt(np.maximum(var_d, 0.0))),
        frequency_hz=fit_x.frequency_hz,
        frequency_se_hz=fit_x.frequency_se_hz,
        x=fit_x,
        y=fit_y,
    )


def delay_between(x: SineFit, y: SineFit, harmonic: int) -> PhaseDelay:
    """Delay of ``y`` behind ``x`` at ``harmonic`` from two fits already made at one frequency, of
    channels whose noise is independent (two fits, not the two halves of one joint fit).

    What :func:`phase_delay` gives at a known frequency, without fitting again: the method fits
    each channel once at the frequency its current and flux found, and reads every delay off those
    fits, so the three delays share one frequency and ``hysteresis + instrument = total`` holds to
    rounding (with magnet).  The phases' variances add; ``frequency_se_hz`` is the larger of the two
    fits' (the one that estimated the frequency; a fit at a given frequency has 0).

    >>> import numpy as np
    >>> fs_hz, f, d = 10_000.0, 320.0, 123.4e-6
    >>> t = np.arange(3000) / fs_hz
    >>> fx = sine_fit(np.sin(2 * np.pi * f * t), fs_hz, f, fit_freq=False)
    >>> fy = sine_fit(3.0 * np.sin(2 * np.pi * f * (t - d)) + 1.0, fs_hz, f, fit_freq=False)
    >>> print(f"{delay_between(fx, fy, 1).delay_s * 1e6:.4f} us")
    123.4000 us
    """
    if not np.array_equal(x.frequency_hz, y.frequency_hz):
        raise ValueError(f"delay_between: the fits are at different frequencies, {x.frequency_hz} and "
                         f"{y.frequency_hz} Hz")
    hx, hy = x.component(harmonic), y.component(harmonic)
    dphi = np.angle(np.exp(1j * (hx.phase_rad - hy.phase_rad)))
    dphi = np.where(dphi <= -np.pi, dphi + _TWO_PI, dphi)
    se = np.hypot(hx.phase_se_rad, hy.phase_se_rad)
    omega = _TWO_PI * harmonic * np.asarray(x.frequency_hz)
    return PhaseDelay(harmonic=int(harmonic), phase_rad=dphi[()], phase_se_rad=se[()], delay_s=(dphi / omega)[()],
                      delay_se_s=(se / omega)[()], frequency_hz=x.frequency_hz,
                      frequency_se_hz=np.maximum(x.frequency_se_hz, y.frequency_se_hz)[()], x=x, y=y)


def find_outliers(
    records: Sequence[np.ndarray],
    fs_hz: float,
    frequency_hz: float | None,
    *,
    harmonics: int | Iterable[int] = 1,
    names: Sequence[str] | None = None,
    outlier_sigmas: float = OUTLIER_SIGMAS,
    search_ppm: float = 200.0,
) -> tuple[list[np.ndarray], float]:
    """Gross outliers of several 1-D channels sampled together, from one joint fit.

    The channels share the frequency (one generator, one clock), so one fit of them all finds the
    frequency and each channel's outliers (as :func:`sine_fit` would, with ``outlier_sigmas``) for
    the price of one: the channels' masks (True: an outlier) and the fitted frequency (Hz).
    ``names`` name the channels in errors (default ``x0``, ``x1``...).

    >>> import numpy as np
    >>> t = np.arange(5000) / 10_000.0
    >>> i, f = np.sin(2 * np.pi * 320 * t), 175 + 45 * np.sin(2 * np.pi * 320 * t - 0.1)
    >>> f[1234] = 1e6
    >>> masks, freq = find_outliers([i, f], 10_000.0, 320.0, names=["current_A", "force_N"])
    >>> [np.flatnonzero(m).tolist() for m in masks], round(freq, 6)
    ([[], [1234]], 320.0)
    """
    names = tuple(names) if names is not None else tuple(f"x{k}" for k in range(len(records)))
    if len(names) != len(records) or not records:
        raise ValueError(f"names must name each of the {len(records)} records, got {list(names)}")
    if any(np.ndim(r) != 1 for r in records):
        raise ValueError("find_outliers takes 1-D records (one recording's channels)")
    sol, mask, *_ = _solve(tuple(records), names, fs_hz, frequency_hz, harmonics, True, search_ppm, 50, 1e-10, -1,
                           None, outlier_sigmas)
    return [mask[0, c] for c in range(len(records))], float(sol.freq[0])


def gross_outliers(x: np.ndarray) -> np.ndarray:
    """Samples of a 1-D record too far out for any fit to start from (more than ``GROSS_MADS``
    median absolute deviations from the median; none if that would be more than 1 % of them), as
    the fits take them out first: what a range or clipping check must not look at.

    >>> x = np.sin(np.linspace(0, 20, 1000))
    >>> x[[10, 500]] = 1e308, -50.0
    >>> np.flatnonzero(gross_outliers(x)).tolist()
    [10]
    """
    x = np.asarray(x, dtype=np.float64)
    if x.ndim != 1:
        raise ValueError(f"x must be a 1-D record, got shape {x.shape}")
    mask = _outliers.initial_mask(x[None, None, :], None, OUTLIER_SIGMAS)
    return np.zeros(x.shape, dtype=bool) if mask is None else mask[0, 0]
