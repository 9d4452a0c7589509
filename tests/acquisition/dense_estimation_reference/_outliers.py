"""Gross outliers: single samples far off the fitted waveform (a glitch, a spike, a bit error),
found per channel and left out of the least-squares fit (private; see :mod:`.sinefit`).

A sample is an outlier when its residual from the fit (DC and the fitted harmonics) lies more than
``sigmas`` robust standard deviations from the channel's median residual.  The robust standard
deviation is 1.4826 times the median absolute deviation (MAD): Gaussian noise gives its standard
deviation, and a few outliers barely move it.  At the default 9 sigmas Gaussian noise trips the
test once in 4e18 samples, so a million-sample record of clean noise never does.  One glitch moves
the first fit by its size over N, so it stands out of that fit's residuals; the fit is repeated
without the outliers found until the set no longer changes (a smaller outlier hidden by a larger
one shows up in the second pass).

Samples so far off that they would swamp the fit itself (1e308 squares to infinity) are taken out
before the first fit: those more than ``GROSS_MADS`` MADs of the raw samples from their median (a
sine's samples stay within 1.5 of its MAD, a distorted one's within a few).
"""

from __future__ import annotations

import numpy as np

from . import _lsq

OUTLIER_SIGMAS = 9.0
GROSS_MADS = 100.0
#: At most this share of a record may be taken out before the first fit; more is no outlier but
#: the signal's shape (a pulse train), left to the fit to judge.
GROSS_MAX_FRACTION = 0.01
MAX_PASSES = 5
_MAD_TO_SIGMA = 1.482602218505602  # 1 / Phi^-1(3/4)
_REL_FLOOR = 1e-9  # robust sigma floor, relative to the record's spread (noiseless data)


def _mad(x: np.ndarray, mask: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """Median and median absolute deviation along the last axis, over samples not masked."""
    if mask is None or not mask.any():
        med = np.median(x, axis=-1, keepdims=True)
        return med, np.median(np.abs(x - med), axis=-1, keepdims=True)
    xm = np.where(mask, np.nan, x)
    med = np.nanmedian(xm, axis=-1, keepdims=True)
    return med, np.nanmedian(np.abs(xm - med), axis=-1, keepdims=True)


def initial_mask(data: np.ndarray, exclude: np.ndarray | None, sigmas: float | None) -> np.ndarray | None:
    """Samples (B, C, N) left out of the first fit: those given, and with detection on the gross
    ones.  None if there are none."""
    mask = None if exclude is None else exclude.copy()
    if sigmas is not None:
        med, mad = _mad(data, mask)
        with np.errstate(invalid="ignore", over="ignore"):
            gross = np.abs(data - med) > GROSS_MADS * mad
        few = gross.sum(axis=-1, keepdims=True) <= GROSS_MAX_FRACTION * data.shape[-1]
        gross &= few
        mask = gross if mask is None else mask | gross
    return mask if mask is not None and mask.any() else None


def _check_left(data: np.ndarray, mask: np.ndarray | None, names: tuple[str, ...], n_params: int) -> None:
    """What is left of each channel must vary and outnumber the fitted parameters."""
    if mask is None:
        return
    left = data.shape[-1] - mask.sum(axis=-1)
    for c, name in enumerate(names):
        if np.any(left[:, c] < n_params + 2):
            raise ValueError(f"{name} has {int(np.min(left[:, c]))} samples left once its outliers are out, "
                             f"too few for {n_params} parameters")
        first_kept = np.take_along_axis(data[:, c], np.argmin(mask[:, c], axis=-1)[:, None], axis=-1)
        kept = np.where(mask[:, c], first_kept, data[:, c])  # an outlier takes a kept sample's value
        if np.any(np.ptp(kept, axis=-1) == 0.0):
            raise ValueError(f"{name} is flat (zero variance) apart from {int(mask[:, c].sum())} outlier "
                             "sample(s): it carries no phase")


def model(sol: _lsq.Solution, ks: tuple[int, ...], fs: float, n: int) -> np.ndarray:
    """The fitted waveforms (B, C, N)."""
    tau = (np.arange(n) - (n - 1) / 2.0) / fs
    return sol.coef @ _lsq._basis(sol.freq, np.asarray(ks, dtype=np.float64), tau)


def robust_solve(data: np.ndarray, fs: float, f0: np.ndarray, ks: tuple[int, ...], *, fit_freq: bool,
                 max_iter: int, tol: float, exclude: np.ndarray | None, mask: np.ndarray | None,
                 sigmas: float | None, names: tuple[str, ...]) -> tuple[_lsq.Solution, np.ndarray | None]:
    """Fit, flag the outliers of each channel, refit without them, until the flags settle.

    ``exclude`` (B, C, N): samples the caller leaves out whatever their values; ``mask``: the
    first fit's (:func:`initial_mask`); ``sigmas`` None: no detection.  Returns the last fit and the
    samples it left out (None: none)."""
    n = data.shape[-1]
    n_params = data.shape[1] * (1 + 2 * len(ks)) + int(fit_freq)
    for k in range(MAX_PASSES):
        _check_left(data, mask, names, n_params)
        sol = _lsq.solve(data, fs, f0, ks, fit_freq=fit_freq, max_iter=max_iter, tol=tol, mask=mask)
        if sigmas is None or k == MAX_PASSES - 1:
            break
        with np.errstate(invalid="ignore", over="ignore"):
            resid = data - model(sol, ks, fs, n)
            med, mad = _mad(resid, mask)
            spread = np.sqrt(np.maximum(sol.sigma2, 0.0))[..., None]
            sigma = np.maximum(_MAD_TO_SIGMA * mad, _REL_FLOOR * np.maximum(spread, np.abs(sol.coef).max(-1)[..., None]))
            flagged = np.abs(resid - med) > sigmas * sigma
        flagged |= ~np.isfinite(resid)
        new = flagged if exclude is None else flagged | exclude
        new_mask = new if new.any() else None
        if (new_mask is None and mask is None) or (new_mask is not None and mask is not None
                                                   and np.array_equal(new_mask, mask)):
            break
        mask = new_mask
        f0 = sol.freq  # the next pass starts where this one ended
    return sol, mask
