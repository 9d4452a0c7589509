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

Most rows have no sample anywhere near the threshold: one histogram of the row proves that
(:func:`._median_kernel.within_mads`) and the row's median and MAD are then not taken at all.

Memory: residuals are made one channel at a time, block by block, and a median needs one copy of
the samples it is taken over; nothing of N x (fitted parameters) size is ever built.
"""

from __future__ import annotations

import threading
from collections import OrderedDict

import numpy as np

from hystbench.jit import enabled

from . import _lsq, _median_kernel

OUTLIER_SIGMAS = 9.0
GROSS_MADS = 100.0
#: At most this share of a record may be taken out before the first fit; more is no outlier but
#: the signal's shape (a pulse train), left to the fit to judge.
GROSS_MAX_FRACTION = 0.01
MAX_PASSES = 5
_MAD_TO_SIGMA = 1.482602218505602  # 1 / Phi^-1(3/4)
_REL_FLOOR = 1e-9  # robust sigma floor, relative to the record's spread (noiseless data)
#: Rows (record channels) are handled a few at a time, about this many samples together, so the
#: copies a median needs stay near one channel's size however many or long the records are.
ROW_SAMPLES = 1 << 20
#: Take a row's median and MAD with the compiled kernel (:mod:`._median_kernel`) when numba runs;
#: False: always with numpy (the reference; tests compare the two in one process).
KERNEL = True


#: The median and MAD of this many recent raw rows are remembered per thread (:func:`_raw_mad`),
#: rows of at most ``RECENT_ROW_SAMPLES`` samples (a live window's).
RECENT_ROWS = 8
RECENT_ROW_SAMPLES = 1 << 17
_recent = threading.local()


def _row_key(row: np.ndarray) -> bytes:
    """A cheap key for a row: its length and about 64 of its samples (hashing a whole 25 000-sample
    row's bytes took 90 us, as long as its median); a hit is then checked against the whole row."""
    return row[:: max(1, row.size // 64)].tobytes() + row.size.to_bytes(8, "little")


def _raw_mad(x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`_mad_top` of raw rows ``x`` (R, N), nothing masked, remembering each row's result:
    the live estimator's window passes each channel through the clipping check and its fits,
    each taking the gross outliers out first (two medians a row), and a median and a MAD are exact
    order statistics, the same numbers whichever way they are taken.  A row is recognised by
    :func:`_row_key` and then its every bit (a copy of it is kept)."""
    if x.dtype != np.float64 or x.shape[-1] > RECENT_ROW_SAMPLES:
        return _mad_top(x)
    recent: OrderedDict[bytes, tuple[np.ndarray, tuple[float, float, float]]] | None = getattr(_recent, "rows", None)
    if recent is None:
        recent = _recent.rows = OrderedDict()
    keys = [_row_key(row) for row in x]
    found = [recent.get(k) for k in keys]
    if all(f is not None and np.array_equal(f[0].view(np.int64), row.view(np.int64)) for f, row in zip(found, x)):
        for k in keys:
            recent.move_to_end(k)
        got = np.array([f[1] for f in found])
        return got[:, :1], got[:, 1:2], got[:, 2:]
    med, mad, top = _mad_top(x)
    for k, row, m, d, t in zip(keys, x, med[:, 0], mad[:, 0], top[:, 0]):
        recent[k] = (row.copy(), (float(m), float(d), float(t)))
        recent.move_to_end(k)
    while len(recent) > RECENT_ROWS:
        recent.popitem(last=False)
    return med, mad, top


def _compiled() -> bool:
    return KERNEL and enabled()


def _mad_top(x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`_mad` of rows ``x`` (R, N), nothing masked, and each row's largest absolute deviation
    from its median (R, 1): a row whose largest is within k MADs has no sample beyond, so its
    N comparisons need not be made.  That largest comes free with the compiled kernel; numpy's
    path gives +inf (unknown: every sample is compared)."""
    if not _compiled() or x.shape[-1] == 0:
        med, mad = _mad(x, None)
        return med, mad, np.full(med.shape, np.inf)
    out = np.empty((x.shape[0], 3))
    for r in range(x.shape[0]):
        out[r] = _median_kernel.median_mad(np.ascontiguousarray(x[r], dtype=np.float64))
    return out[:, :1], out[:, 1:2], out[:, 2:]


def _within(x: np.ndarray, k: float) -> bool:
    """True if no sample of any row of ``x`` (R, N) can be more than ``k`` MADs from its row's
    median (a histogram's bound, :func:`._median_kernel.within_mads`, ~4x cheaper than the median
    and MAD it spares); False: unknown, or numba off."""
    return _compiled() and all(_median_kernel.within_mads(np.ascontiguousarray(row, dtype=np.float64), float(k))
                               for row in x)


def _row_chunks(rows: int, n: int) -> list[slice]:
    step = max(1, ROW_SAMPLES // max(n, 1))
    return [slice(s, min(s + step, rows)) for s in range(0, rows, step)]


def _mad(x: np.ndarray, mask: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """Median and median absolute deviation of rows ``x`` (R, N) over the samples not masked,
    (R, 1) each.  A single long row is done in one copy of its kept samples, reordered in place."""
    if x.shape[0] == 1:
        if _compiled():  # the same order statistics, in one compiled call (on its own copy)
            kept = x[0] if mask is None else x[0][~mask[0]]
            med, mad, _ = (np.nan,) * 3 if kept.size == 0 else _median_kernel.median_mad(
                np.ascontiguousarray(kept, dtype=np.float64))
            return np.full((1, 1), med), np.full((1, 1), mad)
        kept = x[0].copy() if mask is None else x[0][~mask[0]]
        if kept.size == 0:
            return np.full((1, 1), np.nan), np.full((1, 1), np.nan)
        med = np.median(kept, overwrite_input=True)  # the same values, in another order
        np.abs(np.subtract(kept, med, out=kept), out=kept)
        return np.full((1, 1), med), np.full((1, 1), np.median(kept, overwrite_input=True))
    if mask is None or not mask.any():
        med = np.median(x, axis=-1, keepdims=True)
        return med, np.median(np.abs(x - med), axis=-1, keepdims=True)
    xm = np.where(mask, np.nan, x)
    med = np.nanmedian(xm, axis=-1, keepdims=True)
    return med, np.nanmedian(np.abs(xm - med), axis=-1, keepdims=True)


def row_median(data: np.ndarray) -> np.ndarray:
    """Median of every channel (B, C, N) over all its samples, (B, C, 1)."""
    flat = data.reshape(-1, data.shape[-1])
    out = np.empty((flat.shape[0], 1))
    for rows in _row_chunks(*flat.shape):
        out[rows] = np.median(flat[rows], axis=-1, keepdims=True)  # one copy of these rows
    return out.reshape(data.shape[:-1] + (1,))


def initial_mask(data: np.ndarray, exclude: np.ndarray | None, sigmas: float | None) -> np.ndarray | None:
    """Samples (B, C, N) left out of the first fit: those given, and with detection on the gross
    ones.  None if there are none."""
    mask = None if exclude is None else exclude.copy()
    if sigmas is not None:
        n = data.shape[-1]
        flat = data.reshape(-1, n)
        given = None if mask is None else mask.reshape(-1, n)
        gross = np.zeros(flat.shape, dtype=bool)
        for rows in _row_chunks(*flat.shape):
            if given is None:
                if _within(flat[rows], GROSS_MADS):
                    continue  # no sample can be beyond: none is gross (the usual case)
                med, mad, top = _raw_mad(flat[rows])
            else:
                (med, mad), top = _mad(flat[rows], given[rows]), np.inf
            with np.errstate(invalid="ignore", over="ignore"):
                if np.all(top <= GROSS_MADS * mad):
                    continue  # no sample's deviation exceeds the largest: none is gross
                out = np.abs(flat[rows] - med) > GROSS_MADS * mad
            few = out.sum(axis=-1, keepdims=True) <= GROSS_MAX_FRACTION * n
            gross[rows] = out & few
        gross = gross.reshape(data.shape)
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
        keep = ~mask[:, c]
        hi = np.max(data[:, c], axis=-1, where=keep, initial=-np.inf)
        lo = np.min(data[:, c], axis=-1, where=keep, initial=np.inf)
        if np.any(hi == lo):
            raise ValueError(f"{name} is flat (zero variance) apart from {int(mask[:, c].sum())} outlier "
                             "sample(s): it carries no phase")


def _flag(data: np.ndarray, sol: _lsq.Solution, ks: tuple[int, ...], fs_hz: float, mask: np.ndarray | None,
          sigmas: float) -> np.ndarray:
    """Samples (B, C, N) whose residual from the fit ``sol`` lies more than ``sigmas`` robust
    standard deviations (from the samples ``mask`` leaves in) off the channel's median residual,
    or is not finite.  One channel's residual at a time, made block by block."""
    nb, nc, n = data.shape
    kf = np.asarray(ks, dtype=np.float64)
    flagged = np.zeros(data.shape, dtype=bool)
    spread = np.sqrt(np.maximum(sol.sigma2, 0.0))  # (B, C)
    scale = np.maximum(spread, np.abs(sol.coef).max(-1))
    for rows in _row_chunks(nb, n):
        for c in range(nc):
            with np.errstate(invalid="ignore", over="ignore"):
                resid = _lsq.residual_rows(data[rows, c], sol.coef[rows, c], sol.freq[rows], kf, fs_hz)
                if mask is None and _within(resid, sigmas * _MAD_TO_SIGMA):
                    continue  # every residual finite and certainly within (sigma >= 1.4826 MAD)
                if mask is None:
                    med, mad, top = _mad_top(resid)
                else:
                    (med, mad), top = _mad(resid, mask[rows, c]), np.inf
                sigma = np.maximum(_MAD_TO_SIGMA * mad, _REL_FLOOR * scale[rows, c, None])
                if np.all(top <= sigmas * sigma):
                    continue  # every residual finite and within: nothing flagged in this channel
                bad = ~np.isfinite(resid)
                np.abs(np.subtract(resid, med, out=resid), out=resid)
                flagged[rows, c] = (resid > sigmas * sigma) | bad
    return flagged


def robust_solve(data: np.ndarray, fs_hz: float, f0: np.ndarray, ks: tuple[int, ...], *, fit_freq: bool,
                 max_iter: int, tol: float, exclude: np.ndarray | None, mask: np.ndarray | None,
                 sigmas: float | None, names: tuple[str, ...]) -> tuple[_lsq.Solution, np.ndarray | None]:
    """Fit, flag the outliers of each channel, refit without them, until the flags settle.

    ``exclude`` (B, C, N): samples the caller leaves out whatever their values; ``mask``: the
    first fit's (:func:`initial_mask`); ``sigmas`` None: no detection.  Returns the last fit and the
    samples it left out (None: none)."""
    n_params = data.shape[1] * (1 + 2 * len(ks)) + int(fit_freq)
    for k in range(MAX_PASSES):
        _check_left(data, mask, names, n_params)
        sol = _lsq.solve(data, fs_hz, f0, ks, fit_freq=fit_freq, max_iter=max_iter, tol=tol, mask=mask)
        if sigmas is None or k == MAX_PASSES - 1:
            break
        new = _flag(data, sol, ks, fs_hz, mask, sigmas)
        if exclude is not None:
            new |= exclude
        new_mask = new if new.any() else None
        if (new_mask is None and mask is None) or (new_mask is not None and mask is not None
                                                   and np.array_equal(new_mask, mask)):
            break
        mask = new_mask
        f0 = sol.freq  # the next pass starts where this one ended
    return sol, mask
