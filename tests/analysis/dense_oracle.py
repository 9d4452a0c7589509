"""An independent, dense oracle for the block-wise estimators (tests only).

Written from the model, not from the production code: per record, the full N x p design matrix
(a column of ones, cos and sin of each harmonic, time from the record centre) solved by
``np.linalg.lstsq``; the common frequency as the root, by ``scipy.optimize.brentq``, of the
derivative of ``sum_c log S_c`` (the Gaussian likelihood with a noise variance per channel);
the covariance as the inverse of the full information matrix; the outlier rule (robust sigma =
1/Phi^-1(3/4) x the MAD of the residuals of the kept samples, refit until the set is stable) on
whole residual arrays; the start-frequency grid by direct Fourier sums at every grid point; the
paper's Eq. 3 by ``np.correlate`` over whole records.  No input checks: the tests pass good input.
Definitions it must share with the production code (the thresholds, the rounding floor of the
noise variance, the shared frequency's share of the degrees of freedom) are stated here or
imported as constants.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import brentq
from scipy.stats import norm

from hystbench.analysis.estimation._outliers import GROSS_MADS, GROSS_MAX_FRACTION, MAX_PASSES, OUTLIER_SIGMAS

MAD_TO_SIGMA = 1.0 / norm.ppf(0.75)
REL_FLOOR = 1e-9  # robust sigma floor relative to the channel's scale (noiseless data)
EPS = np.finfo(np.float64).eps


@dataclass
class DenseFit:
    """One record's joint fit of channels c: coef (C, p) = [offset, a_1, s_1, a_2, s_2, ...] of
    ``offset + sum a_k cos(2 pi k f tau) + s_k sin(2 pi k f tau)``; cov over all C p coefficients
    (then the frequency, if fitted); sigma2 (C,) noise variances; mask (C, N) samples left out."""

    freq: float
    coef: np.ndarray
    cov: np.ndarray
    sigma2: np.ndarray
    mask: np.ndarray

    def phase(self, c: int, j: int) -> tuple[float, np.ndarray]:
        """Phase atan2(-s, a) of channel c's j-th harmonic and its gradient over the parameters."""
        p = self.coef.shape[1]
        a, s = self.coef[c, 1 + 2 * j], self.coef[c, 2 + 2 * j]
        grad = np.zeros(self.cov.shape[0])
        grad[c * p + 1 + 2 * j], grad[c * p + 2 + 2 * j] = s / (a * a + s * s), -a / (a * a + s * s)
        return float(np.arctan2(-s, a)), grad

    def se(self, grad: np.ndarray) -> float:
        return float(np.sqrt(grad @ self.cov @ grad))


def _design(n: int, fs: float, f: float, ks) -> tuple[np.ndarray, np.ndarray]:
    tau = (np.arange(n) - (n - 1) / 2.0) / fs
    cols = [np.ones(n)] + [fn(2 * np.pi * k * f * tau) for k in ks for fn in (np.cos, np.sin)]
    return tau, np.column_stack(cols)


def _linear(data, keep, fs, f, ks):
    """Least squares at frequency f: design, coefficients (C, p), residuals (C, N) of all samples,
    residual sums of squares over the kept ones, and d(model)/df (C, N)."""
    tau, basis = _design(data.shape[1], fs, f, ks)
    coef = np.stack([np.linalg.lstsq(basis[k], x[k], rcond=None)[0] for x, k in zip(data, keep)])
    with np.errstate(over="ignore", invalid="ignore"):
        resid = data - coef @ basis.T
    ssq = np.array([r[k] @ r[k] for r, k in zip(resid, keep)])
    dfreq = sum(2 * np.pi * k * tau * (coef[:, 2 + 2 * j, None] * basis[:, 1 + 2 * j]
                                        - coef[:, 1 + 2 * j, None] * basis[:, 2 + 2 * j]) for j, k in enumerate(ks))
    return basis, coef, resid, ssq, dfreq


def _fit(data, fs, f, ks, fit_freq, mask) -> DenseFit:
    nc, n = data.shape
    keep = ~mask
    used = keep.sum(axis=1)
    # rounding floor of S_c (noiseless data): as in the production code's definition
    rms = np.sqrt(np.sum(np.where(keep, data, 0.0) ** 2, axis=1) / used)
    floor = used * (64 * EPS * rms) ** 2 + np.finfo(float).tiny
    if fit_freq:  # root of -d/df sum_c log(S_c + floor_c) = 2 sum_c g_c.r_c / (S_c + floor_c)
        def slope(fr):
            _, _, r, s, g = _linear(data, keep, fs, fr, ks)
            return float(np.sum(np.sum(g * np.where(keep, r, 0.0), axis=1) / (s + floor)))

        for half in fs / (n * ks[-1]) * 2.0 ** -np.arange(12.0, 0.0, -1.0):  # 1/4096 .. 1/2 bin around f
            if slope(f - half) > 0 > slope(f + half):  # a maximum of the likelihood in between
                f = brentq(slope, f - half, f + half, xtol=1e-15 * f, rtol=4 * EPS, maxiter=200)
                break
        else:
            raise AssertionError(f"no likelihood maximum within half a bin of {f} Hz")
    basis, coef, resid, ssq, dfreq = _linear(data, keep, fs, f, ks)
    p = basis.shape[1]
    dof = used - p - (1.0 / nc if fit_freq else 0.0)  # the shared frequency counts 1/C per channel
    sigma2 = np.maximum(ssq, floor) / dof
    q = nc * p + int(fit_freq)
    info = np.zeros((q, q))
    for c in range(nc):
        jac = np.column_stack([basis, dfreq[c]]) if fit_freq else basis
        idx = np.r_[c * p : (c + 1) * p, [q - 1] if fit_freq else []].astype(int)
        info[np.ix_(idx, idx)] += jac[keep[c]].T @ jac[keep[c]] / sigma2[c]
    scale = np.sqrt(np.diag(info))
    cov = np.linalg.inv(info / np.outer(scale, scale)) / np.outer(scale, scale)
    return DenseFit(float(f), coef, cov, sigma2, mask.copy())


def robust_fit(data, fs: float, f: float, ks, *, fit_freq: bool = True, exclude=None,
               sigmas: float | None = OUTLIER_SIGMAS) -> DenseFit:
    """Joint fit of channels ``data`` (C, N) with outliers found and left out.

    ``f``: the frequency (``fit_freq`` False) or where to look for it: the first fit's within half a
    bin of it, each later fit's within half a bin of the one before (as a refit starts there)."""
    data = np.asarray(data, dtype=np.float64)
    exclude = np.zeros(data.shape, bool) if exclude is None else np.asarray(exclude, bool)
    mask = exclude.copy()
    if sigmas is not None:  # gross outliers out before the first fit: > GROSS_MADS MADs of the raw samples
        for c, (x, m) in enumerate(zip(data, exclude)):
            med = np.median(x[~m])
            out = np.abs(x - med) > GROSS_MADS * np.median(np.abs(x[~m] - med))
            if out.sum() <= GROSS_MAX_FRACTION * x.size:
                mask[c] |= out
    for npass in range(MAX_PASSES):
        fit = _fit(data, fs, f, tuple(ks), fit_freq, mask)
        if sigmas is None or npass == MAX_PASSES - 1:
            return fit
        with np.errstate(over="ignore", invalid="ignore"):
            resid = data - fit.coef @ _design(data.shape[1], fs, fit.freq, ks)[1].T
        new = exclude.copy()
        for c, (r, m) in enumerate(zip(resid, mask)):
            med = np.median(r[~m])
            scale = max(np.sqrt(fit.sigma2[c]), np.max(np.abs(fit.coef[c])))
            sigma = max(MAD_TO_SIGMA * np.median(np.abs(r[~m] - med)), REL_FLOOR * scale)
            new[c] |= ~(np.abs(r - med) <= sigmas * sigma)  # NaN and inf count as outliers
        if np.array_equal(new, mask):
            return fit
        mask, f = new, fit.freq
    raise AssertionError("unreachable")


def phase_delay(fit: DenseFit, ks, harmonic: int, fit_freq: bool = True) -> tuple[float, float]:
    """Delay (s) of channel 1 behind channel 0 at ``harmonic`` and its standard error."""
    j = tuple(ks).index(harmonic)
    (phi_x, gx), (phi_y, gy) = fit.phase(0, j), fit.phase(1, j)
    omega = 2 * np.pi * harmonic * fit.freq
    delay = float(np.angle(np.exp(1j * (phi_x - phi_y)))) / omega
    grad = (gx - gy) / omega
    if fit_freq:
        grad[-1] = -delay / fit.freq
    return delay, fit.se(grad)


def grid_start(x: np.ndarray, fs: float, f_c: float, ks, half_width_hz: float) -> np.ndarray:
    """Per record (B, C, N): the point of the quarter-bin grid over ``f_c +- half_width_hz`` with the
    largest power of harmonics ``ks``, summed over the channels (each centred, unit norm), by
    direct Fourier sums at every grid point."""
    n = x.shape[-1]
    spacing = 0.25 * fs / (n * ks[-1])
    half = int(np.ceil(half_width_hz / spacing))
    grid = f_c + spacing * np.arange(-half, half + 1)
    tau = (np.arange(n) - (n - 1) / 2.0) / fs
    xc = x - x.mean(axis=-1, keepdims=True)
    xc /= np.linalg.norm(xc, axis=-1, keepdims=True)
    power = np.array([sum(np.sum(np.abs(xc @ np.exp(-2j * np.pi * k * f * tau)) ** 2, axis=-1) for k in ks)
                      for f in grid])  # (grid, B)
    return grid[np.argmax(power, axis=0)]


def covariance_delay(x: np.ndarray, y: np.ndarray, fs: float, freq_hz: float) -> tuple[int, float, np.ndarray]:
    """The paper's Eq. 3 for one record: lag (samples) of the largest covariance over one period of
    lags (x cut to leave room for all of them), that covariance, and the lags searched."""
    period = int(round(fs / freq_hz))
    half, width = period // 2, x.size - period + 1
    xw = x[half : half + width]
    cov = np.correlate(y - y.mean(), xw - xw.mean(), mode="valid") / width  # cov[j]: lag j - half
    lags = np.arange(period) - half
    j = int(np.argmax(cov))
    return int(lags[j]), float(cov[j]), lags
