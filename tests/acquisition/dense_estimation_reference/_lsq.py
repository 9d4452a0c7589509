"""The least-squares engine behind :mod:`.sinefit` (private).

Model of channel ``c`` of record ``b`` (the channels of one record share the frequency)::

    x[b, c, n] = d[b, c] + sum_k ( a[b, c, k] cos(2 pi k f[b] tau_n) + s[b, c, k] sin(2 pi k f[b] tau_n) )
    tau_n = (n - (N - 1) / 2) / fs            # time from the record centre (s)

The parameters are linear except ``f``.  For a given ``f`` the linear ones follow from one small
normal-equation solve; ``f`` is found by variable projection: Gauss-Newton steps on the
concentrated cost ``L(f) = sum_c log S_c(f)`` (``S_c`` = residual sum of squares of channel c),
which is the Gaussian log-likelihood with an unknown noise variance per channel.  For one channel
this is ordinary least squares (IEEE Std 1057/1241 four-parameter fit); for several it weights
each channel by its own residual variance, so the cleaner channel dominates the frequency.  A step
is kept only if ``L`` does not grow, otherwise it is halved; steps are clipped to a quarter of a
DFT bin of the highest harmonic, so a start within about one bin converges.  The search stops
when the last step moves the phase at the record ends by less than ``tol`` or is below 1e-6 of
the frequency's standard error (steps that small are lost in the rounding of ``L``).

Everything is vectorised over records ``b``; records that have converged drop out of the loop.
Samples can be left out per channel (``mask``, e.g. outliers): they then weigh nothing, exactly as
if they were not there (the Gram matrix loses their outer products, the degrees of freedom their
count), while the time axis stays uniform.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

_TWO_PI = 2.0 * np.pi
_EPS = np.finfo(np.float64).eps
_STAT_TOL = 1e-6  # also stop once the frequency step is this small against its standard error


@dataclass
class Solution:
    """Raw result for records ``b`` (flattened batch) and channels ``c``."""

    freq: np.ndarray  # (B,) Hz
    coef: np.ndarray  # (B, C, p): [d, a_1, s_1, a_2, s_2, ...]
    dof: np.ndarray  # (B, C) residual degrees of freedom
    cov: np.ndarray  # (B, q, q), q = C p (+1 if fit_freq, frequency last)
    sigma2: np.ndarray  # (B, C) residual noise variance
    iterations: np.ndarray  # (B,) int
    converged: np.ndarray  # (B,) bool


def _basis(f: np.ndarray, ks: np.ndarray, tau: np.ndarray) -> np.ndarray:
    """Regressors (b, p, N): a row of ones, then cos, sin for each harmonic.  One cos and one sin
    of the fundamental; the harmonics follow by angle addition (k x eps of rounding at most)."""
    phase = (_TWO_PI * f)[:, None] * tau[None, :]
    basis = np.empty((f.shape[0], 1 + 2 * ks.size, tau.size))
    basis[:, 0] = 1.0
    c1, s1 = np.cos(phase), np.sin(phase)
    c, s = c1, s1
    rows = {int(k): j for j, k in enumerate(ks)}
    for k in range(1, int(ks[-1]) + 1):
        if k > 1:
            c, s = c * c1 - s * s1, s * c1 + c * s1
        if k in rows:
            basis[:, 1 + 2 * rows[k]] = c
            basis[:, 2 + 2 * rows[k]] = s
    return basis


def _linear(x: np.ndarray, basis: np.ndarray, mask: np.ndarray | None):
    """Linear LS at fixed frequency: coefficients (b, C, p), residuals (b, C, N) (0 where masked),
    Gram matrices (b, 1, p, p), or (b, C, p, p) per channel with a ``mask`` of left-out samples
    (``x`` must hold 0 there)."""
    bt = np.swapaxes(basis, -1, -2)
    gram = (basis @ bt)[:, None]
    if mask is not None:  # few samples left out: subtract their outer products
        gram = np.repeat(gram, x.shape[1], axis=1)
        for b, c in zip(*np.nonzero(mask.any(axis=-1))):
            e = basis[b][:, mask[b, c]]
            gram[b, c] -= e @ e.T
    coef = np.linalg.solve(gram, (x @ bt)[..., None])[..., 0]
    resid = x - coef @ basis
    if mask is not None:
        resid[mask] = 0.0
    return coef, resid, gram


def _freq_column(coef: np.ndarray, basis: np.ndarray, ks: np.ndarray, tau: np.ndarray) -> np.ndarray:
    """d(model)/df (b, C, N) = 2 pi tau sum_k k (s_k cos - a_k sin)."""
    kc = coef[..., 2::2] * ks  # sine coefficients times k
    ka = coef[..., 1::2] * ks
    return _TWO_PI * tau * (kc @ basis[:, 1::2] - ka @ basis[:, 2::2])


def solve(
    x: np.ndarray,
    fs: float,
    f0: np.ndarray,
    harmonics: tuple[int, ...],
    *,
    fit_freq: bool,
    max_iter: int,
    tol: float,
    mask: np.ndarray | None = None,
) -> Solution:
    """Fit records ``x`` of shape (B, C, N) starting from frequencies ``f0`` (B,); ``mask`` (B, C,
    N, bool) marks samples to leave out (their values are not used)."""
    nb, nc, n = x.shape
    if mask is not None and not mask.any():
        mask = None
    if mask is not None:
        x = np.where(mask, 0.0, x)
    ks = np.asarray(harmonics, dtype=np.float64)
    p = 1 + 2 * ks.size
    tau = (np.arange(n) - (n - 1) / 2.0) / fs
    duration = n / fs
    max_step = 0.25 / (ks[-1] * duration)  # a quarter DFT bin of the highest harmonic
    used = np.full((nb, nc), float(n)) if mask is None else n - mask.sum(axis=-1).astype(np.float64)
    # rounding floor of S_c, keeps log S and the weights finite for noiseless data
    dof = used - p - (1.0 / nc if fit_freq else 0.0)  # residual degrees of freedom per channel
    floor = used * (64.0 * _EPS * np.sqrt(np.sum(x * x, axis=-1) / used)) ** 2 + np.finfo(np.float64).tiny

    freq = np.array(f0, dtype=np.float64)
    coef = np.zeros((nb, nc, p))
    ssq = np.zeros((nb, nc))
    gram = np.zeros((nb, 1 if mask is None else nc, p, p))
    bg = np.zeros((nb, nc, p))
    gg = np.zeros((nb, nc))
    iterations = np.zeros(nb, dtype=np.int64)
    converged = np.zeros(nb, dtype=bool)

    if not fit_freq:
        basis = _basis(freq, ks, tau)
        coef, resid, gram = _linear(x, basis, mask)
        ssq = np.einsum("bcn,bcn->bc", resid, resid)
        iterations[:] = 1
        converged[:] = True
    else:
        best = np.full(nb, np.inf)
        step = np.zeros(nb)
        f_se = np.zeros(nb)  # standard error of the frequency, for the stopping rule
        active = np.arange(nb)
        for it in range(1, max_iter + 1):
            xa = x if active.size == nb else x[active]
            ma = None if mask is None else mask if active.size == nb else mask[active]
            f_try = freq[active] + step[active]
            basis = _basis(f_try, ks, tau)
            c_try, resid, g_try = _linear(xa, basis, ma)
            s_try = np.einsum("bcn,bcn->bc", resid, resid)
            cost = np.sum(np.log(s_try + floor[active]), axis=-1)
            iterations[active] = it

            better = cost <= best[active]
            keep = active[better]
            freq[keep] = f_try[better]
            best[keep] = cost[better]
            coef[keep] = c_try[better]
            ssq[keep] = s_try[better]
            gram[keep] = g_try[better]

            # Gauss-Newton step (variable projection) for the records that improved
            basis, resid, c_try, g_try = basis[better], resid[better], c_try[better], g_try[better]
            g = _freq_column(c_try, basis, ks, tau)
            if ma is not None:
                g[ma[better]] = 0.0
            g_b = g @ np.swapaxes(basis, -1, -2)  # (b, C, p)
            g_g = np.einsum("bcn,bcn->bc", g, g)
            bg[keep], gg[keep] = g_b, g_g
            g_r = np.einsum("bcn,bcn->bc", g, resid)
            proj = np.einsum("bcp,bcp->bc", g_b, np.linalg.solve(g_try, g_b[..., None])[..., 0])
            weight = 1.0 / (ssq[keep] + floor[keep])
            num = np.sum(weight * g_r, axis=-1)
            den = np.sum(weight * np.maximum(g_g - proj, 0.0), axis=-1)
            with np.errstate(divide="ignore", invalid="ignore"):
                new_step = np.where(den > 0.0, num / den, 0.0)
                f_se[keep] = 1.0 / np.sqrt(np.min(dof[keep], axis=-1) * den)
            step[keep] = np.clip(new_step, -max_step, max_step)
            worse = active[~better]
            step[worse] *= 0.5

            small = np.maximum(tol / (np.pi * ks[-1] * duration), _STAT_TOL * f_se[active])
            done = np.abs(step[active]) < small
            converged[active[done]] = True
            active = active[~done]
            if active.size == 0:
                break

    # covariance of all parameters from the information matrix, noise variance from the residuals
    sigma2 = np.maximum(ssq, floor) / dof
    q = nc * p + 1
    info = np.zeros((nb, q, q))
    for c in range(nc):
        blk = slice(c * p, (c + 1) * p)
        w = (1.0 / sigma2[:, c])[:, None]
        info[:, blk, blk] = gram[:, min(c, gram.shape[1] - 1)] * w[..., None]
        info[:, blk, -1] = bg[:, c] * w
        info[:, -1, blk] = bg[:, c] * w
        info[:, -1, -1] += gg[:, c] * w[:, 0]
    if not fit_freq:
        info = info[:, :-1, :-1]
    scale = np.sqrt(np.diagonal(info, axis1=-2, axis2=-1))
    outer = scale[:, :, None] * scale[:, None, :]
    cov = np.linalg.inv(info / outer) / outer
    return Solution(freq, coef, dof, cov, sigma2, iterations, converged)


def fft_peak_freq(x: np.ndarray, fs: float) -> np.ndarray:
    """Strongest spectral line of records (B, C, N), summed over channels (Hz, per record).

    Hann window, 4x zero padding, parabolic interpolation of the log power around the peak;
    the DC bins are skipped.
    """
    n = x.shape[-1]
    nfft = 4 * n
    win = np.hanning(n + 2)[1:-1]
    xc = (x - x.mean(axis=-1, keepdims=True)) * win
    power = np.abs(np.fft.rfft(xc, nfft, axis=-1)) ** 2
    power = np.sum(power / np.sum(power, axis=-1, keepdims=True), axis=-2)  # (B, nfft/2+1)
    lo = 8  # two bins of the unpadded transform: the window's DC main lobe
    i = lo + np.argmax(power[:, lo:-1], axis=-1)
    around = np.stack([i - 1, i, i + 1], axis=-1)
    lp = np.log(np.take_along_axis(power, around, axis=-1) + np.finfo(np.float64).tiny)
    lm, l0, lq = lp[:, 0], lp[:, 1], lp[:, 2]
    den = lm - 2.0 * l0 + lq
    with np.errstate(divide="ignore", invalid="ignore"):
        delta = np.where(den < 0.0, 0.5 * (lm - lq) / den, 0.0)
    return (i + np.clip(delta, -0.5, 0.5)) * fs / nfft


def grid_start(x: np.ndarray, fs: float, f_c: float, harmonics: tuple[int, ...], half_width_hz: float) -> np.ndarray:
    """Best start frequency per record within ``f_c +- half_width_hz`` (Hz).

    A window within half a DFT bin (of the highest harmonic) is already inside the Gauss-Newton
    basin, so ``f_c`` is returned unchanged.  A wider one is scanned on a grid a quarter bin
    apart for the largest summed power of the requested harmonics (channels normalised); the
    phasors of successive grid points follow by rotation, without new trigonometric calls.
    """
    nb, nc, n = x.shape
    ks = np.asarray(harmonics, dtype=np.float64)
    bin_hz = fs / (n * ks[-1])
    if half_width_hz <= 0.5 * bin_hz:
        return np.full(nb, f_c)
    spacing = 0.25 * bin_hz
    half = int(np.ceil(half_width_hz / spacing))
    grid = f_c + spacing * np.arange(-half, half + 1)
    tau = (np.arange(n) - (n - 1) / 2.0) / fs
    xc = x - x.mean(axis=-1, keepdims=True)
    xc = (xc / np.sqrt(np.sum(xc * xc, axis=-1, keepdims=True))).reshape(nb * nc, n)
    arg = _TWO_PI * (grid[0] * ks)[:, None] * tau  # (K, N)
    cos, sin = np.cos(arg), np.sin(arg)
    arg = _TWO_PI * (spacing * ks)[:, None] * tau
    cos_step, sin_step = np.cos(arg), np.sin(arg)
    power = np.empty((nb, grid.size))
    for g in range(grid.size):
        if g:  # rotate every phasor on by one grid step
            cos, sin = cos * cos_step - sin * sin_step, sin * cos_step + cos * sin_step
        # einsum, not matmul: a BLAS call per tiny product is slow when threads contend
        re, im = np.einsum("rn,kn->rk", xc, cos), np.einsum("rn,kn->rk", xc, sin)  # (B C, K)
        power[:, g] = np.sum((re * re + im * im).reshape(nb, -1), axis=-1)
    return grid[np.argmax(power, axis=-1)]
