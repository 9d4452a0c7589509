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
Along the time axis the sums are taken block by block (``BLOCK`` samples): the regressors of a
block are made, used and dropped, so the memory a fit needs does not grow with the record (a
60 s recording at 100 kS/s has 6e6 samples; its N x 9 regressor matrix alone would be 412 MiB),
and a block's temporaries stay in the processor's cache.
Samples can be left out per channel (``mask``, e.g. outliers): they then weigh nothing, exactly as
if they were not there (the Gram matrix loses their outer products, the degrees of freedom their
count), while the time axis stays uniform.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.signal import CZT

_TWO_PI = 2.0 * np.pi
_EPS = np.finfo(np.float64).eps
_STAT_TOL = 1e-6  # also stop once the frequency step is this small against its standard error
BLOCK = 1 << 14  # samples of a record per block: its temporaries, ~p x BLOCK floats, stay in cache
MIN_BLOCK = 256  # ... but at least this many of each record (many short records share a block)


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


def blocks(n: int, records: int) -> list[slice]:
    """Sample ranges that keep the temporaries of ``records`` records near ``BLOCK`` samples each
    (at least ``MIN_BLOCK`` samples of every record: many short records go in one block)."""
    step = max(MIN_BLOCK, BLOCK // max(records, 1))
    return [slice(s, min(s + step, n)) for s in range(0, n, step)]


def times(sl: slice, n: int, fs: float) -> np.ndarray:
    """Time of samples ``sl`` from the centre of an ``n``-sample record (s); the same numbers,
    element by element, as the whole record's time axis."""
    return (np.arange(sl.start, sl.stop) - (n - 1) / 2.0) / fs


def _block(x: np.ndarray, mask: np.ndarray | None, rows, sl: slice):
    """Samples ``sl`` of records ``rows`` (left-out samples set to 0) and their mask (None: none)."""
    xs = x[rows, :, sl]
    if mask is None:
        return xs, None
    ms = mask[rows, :, sl]
    if not ms.any():
        return xs, None
    return np.where(ms, 0.0, xs), ms


def _sum_squares(x: np.ndarray, mask: np.ndarray | None) -> np.ndarray:
    """Sum of squares of each channel (B, C) over the samples kept."""
    out = np.zeros(x.shape[:2])
    for sl in blocks(x.shape[-1], x.shape[0]):
        xs, _ = _block(x, mask, slice(None), sl)
        out += np.einsum("bcn,bcn->bc", xs, xs)
    return out


def _normal(x, mask, rows, f, ks, fs):
    """Normal equations at frequencies ``f`` of records ``rows``, summed block by block: Gram
    matrices (b, 1, p, p), or (b, C, p, p) per channel when samples are left out, and the
    projections (b, C, p) of the data on the regressors."""
    n, nc, nr = x.shape[-1], x.shape[1], f.shape[0]
    p = 1 + 2 * ks.size
    gram = np.zeros((nr, 1 if mask is None else nc, p, p))
    proj = np.zeros((nr, nc, p))
    for sl in blocks(n, nr):
        basis = _basis(f, ks, times(sl, n, fs))
        bt = np.swapaxes(basis, -1, -2)
        xs, ms = _block(x, mask, rows, sl)
        if ms is None:
            gram += (basis @ bt)[:, None]
        else:  # a left-out sample weighs nothing in its channel's Gram matrix
            gram += (basis[:, None] * ~ms[:, :, None, :]) @ bt[:, None]
        proj += xs @ bt
    return gram, proj


def _residual_sums(x, mask, rows, f, ks, fs, coef, grad: bool):
    """Residual sums of squares (b, C) of the fit ``coef`` at frequencies ``f``, block by block;
    with ``grad`` also what the Gauss-Newton step needs of the frequency column g = d(model)/df:
    g's projections on the regressors (b, C, p), g.g and g.residual (b, C)."""
    n, nc, nr = x.shape[-1], x.shape[1], f.shape[0]
    ssq = np.zeros((nr, nc))
    gb, gg, gr = np.zeros((nr, nc, coef.shape[-1])), np.zeros((nr, nc)), np.zeros((nr, nc))
    kc = coef[..., 2::2] * ks  # sine coefficients times k
    ka = coef[..., 1::2] * ks
    for sl in blocks(n, nr):
        tau = times(sl, n, fs)
        basis = _basis(f, ks, tau)
        xs, ms = _block(x, mask, rows, sl)
        resid = xs - coef @ basis
        if ms is not None:
            resid[ms] = 0.0
        ssq += np.einsum("bcn,bcn->bc", resid, resid)
        if grad:
            g = _TWO_PI * tau * (kc @ basis[:, 1::2] - ka @ basis[:, 2::2])  # (b, C, L)
            if ms is not None:
                g[ms] = 0.0
            gb += g @ np.swapaxes(basis, -1, -2)
            gg += np.einsum("bcn,bcn->bc", g, g)
            gr += np.einsum("bcn,bcn->bc", g, resid)
    return ssq, gb, gg, gr


def residual_rows(x: np.ndarray, coef: np.ndarray, freq: np.ndarray, ks: np.ndarray, fs: float) -> np.ndarray:
    """Residuals (R, N) of 1-D records ``x`` (R, N) from fits ``coef`` (R, p) at ``freq`` (R,),
    computed block by block: the only N-sized array is the result."""
    n = x.shape[-1]
    out = np.empty(x.shape)
    for sl in blocks(n, x.shape[0]):
        out[:, sl] = x[:, sl] - (coef[:, None, :] @ _basis(freq, ks, times(sl, n, fs)))[:, 0]
    return out


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
    N, bool) marks samples to leave out (their values are not used).

    Each evaluation at a trial frequency takes two passes over the samples, block by block (the
    normal equations, then the residuals and the frequency column at the solved coefficients),
    so no N x p regressor matrix ever exists, whatever N."""
    nb, nc, n = x.shape
    if mask is not None and not mask.any():
        mask = None
    ks = np.asarray(harmonics, dtype=np.float64)
    p = 1 + 2 * ks.size
    duration = n / fs
    max_step = 0.25 / (ks[-1] * duration)  # a quarter DFT bin of the highest harmonic
    used = np.full((nb, nc), float(n)) if mask is None else n - mask.sum(axis=-1).astype(np.float64)
    # rounding floor of S_c, keeps log S and the weights finite for noiseless data
    dof = used - p - (1.0 / nc if fit_freq else 0.0)  # residual degrees of freedom per channel
    floor = used * (64.0 * _EPS * np.sqrt(_sum_squares(x, mask) / used)) ** 2 + np.finfo(np.float64).tiny

    freq = np.array(f0, dtype=np.float64)
    coef = np.zeros((nb, nc, p))
    ssq = np.zeros((nb, nc))
    gram = np.zeros((nb, 1 if mask is None else nc, p, p))
    bg = np.zeros((nb, nc, p))
    gg = np.zeros((nb, nc))
    iterations = np.zeros(nb, dtype=np.int64)
    converged = np.zeros(nb, dtype=bool)

    if not fit_freq:
        gram, proj = _normal(x, mask, slice(None), freq, ks, fs)
        coef = np.linalg.solve(gram, proj[..., None])[..., 0]
        ssq = _residual_sums(x, mask, slice(None), freq, ks, fs, coef, grad=False)[0]
        iterations[:] = 1
        converged[:] = True
    else:
        best = np.full(nb, np.inf)
        step = np.zeros(nb)
        f_se = np.zeros(nb)  # standard error of the frequency, for the stopping rule
        active = np.arange(nb)
        for it in range(1, max_iter + 1):
            rows = slice(None) if active.size == nb else active
            f_try = freq[active] + step[active]
            g_try, proj = _normal(x, mask, rows, f_try, ks, fs)
            c_try = np.linalg.solve(g_try, proj[..., None])[..., 0]
            s_try, g_b, g_g, g_r = _residual_sums(x, mask, rows, f_try, ks, fs, c_try, grad=True)
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
            g_try, g_b, g_g, g_r = g_try[better], g_b[better], g_g[better], g_r[better]
            bg[keep], gg[keep] = g_b, g_g
            proj_g = np.einsum("bcp,bcp->bc", g_b, np.linalg.solve(g_try, g_b[..., None])[..., 0])
            weight = 1.0 / (ssq[keep] + floor[keep])
            num = np.sum(weight * g_r, axis=-1)
            den = np.sum(weight * np.maximum(g_g - proj_g, 0.0), axis=-1)
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


def grid_start(x: np.ndarray, fs: float, f_c: float, harmonics: tuple[int, ...], half_width_hz: float,
               mask: np.ndarray | None = None, fill: np.ndarray | None = None) -> np.ndarray:
    """Best start frequency per record within ``f_c +- half_width_hz`` (Hz).

    A window within half a DFT bin (of the highest harmonic) is already inside the Gauss-Newton
    basin, so ``f_c`` is returned unchanged.  A wider one is scanned on a grid a quarter bin
    apart for the largest summed power of the requested harmonics (channels normalised).  Samples
    under ``mask`` (B, C, N) count as their channel's ``fill`` value (B, C).

    The grid has ~N points (a bin is fs / N wide), so evaluating each point's Fourier sum directly
    would cost N^2; instead the record goes in blocks, each transformed onto the whole grid at
    once by a chirp-z transform (three FFTs of a block's length), and the blocks' sums are added
    with the phase of their start time: O(N log block) time, memory of a few blocks.
    """
    nb, nc, n = x.shape
    ks = np.asarray(harmonics, dtype=np.float64)
    bin_hz = fs / (n * ks[-1])
    if half_width_hz <= 0.5 * bin_hz:
        return np.full(nb, f_c)
    spacing = 0.25 * bin_hz
    half = int(np.ceil(half_width_hz / spacing))
    grid = f_c + spacing * np.arange(-half, half + 1)
    step = max(MIN_BLOCK, BLOCK // (nb * nc), 4 * grid.size)  # a block much longer than the grid
    parts = [slice(s, min(s + step, n)) for s in range(0, n, step)]

    def filled(sl: slice) -> np.ndarray:
        xs = x[:, :, sl]
        return xs if mask is None else np.where(mask[:, :, sl], fill[..., None], xs)

    # channels centred and scaled to unit norm (two passes: the mean, then the sum of squares)
    mean = sum(np.sum(filled(sl), axis=-1) for sl in parts)[..., None] / n
    norm = np.sqrt(sum(np.sum((filled(sl) - mean) ** 2, axis=-1) for sl in parts))[..., None]
    # sum_n x_n exp(-i 2 pi k f_g tau_n) over a block starting at tau_s, for f_g = grid[0] + g spacing:
    # exp(-i 2 pi k f_g tau_s) sum_m x_{s+m} A^-m W^(m g), A = exp(i 2 pi k grid[0] / fs),
    # W = exp(-i 2 pi k spacing / fs): a chirp-z transform of the block.
    transforms: dict[tuple[int, int], CZT] = {}
    acc = np.zeros((nb * nc, ks.size, grid.size), dtype=np.complex128)
    for sl in parts:
        xc = ((filled(sl) - mean) / norm).reshape(nb * nc, -1)
        tau_s = (sl.start - (n - 1) / 2.0) / fs
        for j, k in enumerate(ks):
            key = (xc.shape[-1], j)
            if key not in transforms:
                transforms[key] = CZT(xc.shape[-1], grid.size, w=np.exp(-2j * np.pi * k * spacing / fs),
                                      a=np.exp(2j * np.pi * k * grid[0] / fs))
            acc[:, j] += transforms[key](xc) * np.exp(-2j * np.pi * k * grid * tau_s)
    power = np.sum((acc.real ** 2 + acc.imag ** 2).reshape(nb, -1, grid.size), axis=1)  # (B, grid)
    return grid[np.argmax(power, axis=-1)]
