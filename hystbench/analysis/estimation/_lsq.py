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
and a block's temporaries stay in the processor's cache.  Short records are the exception that
pays: a live window's regressors (25 000 samples x 9, 1.8 MB) are kept (:func:`bases`), as both
passes of an evaluation and the next fits of the window at the same frequency need them; making
their cos and sin was two thirds of the live estimator's time.  When numba runs, the regressors
come from a compiled kernel (:mod:`._lsq_kernel`: the fundamental rotated sample by sample,
re-anchored exactly every 64, ~8x faster than numpy's cos and sin) and the small normal equations
are solved by a compiled Cholesky; both equal the numpy path (the reference) to rounding.
Samples can be left out per channel (``mask``, e.g. outliers): they then weigh nothing, exactly as
if they were not there (the Gram matrix loses their outer products, the degrees of freedom their
count), while the time axis stays uniform.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from dataclasses import dataclass

import numpy as np
from scipy.signal import CZT

from hystbench.jit import enabled

from . import _lsq_kernel

_TWO_PI = 2.0 * np.pi
_EPS = np.finfo(np.float64).eps
_STAT_TOL = 1e-6  # also stop once the frequency step is this small against its standard error
BLOCK = 1 << 14  # samples of a record per block: its temporaries, ~p x BLOCK floats, stay in cache
MIN_BLOCK = 256  # ... but at least this many of each record (many short records share a block)
#: An evaluation's regressors are kept between its two passes when they hold at most this many
#: floats (8 MiB; a live window's 25 000 samples x 9 take 1.8 MB), else made again for the second.
KEEP_FLOATS = 1 << 20
#: ... and up to this many floats of the latest evaluations' regressors, per thread (16 MiB).
RECENT_FLOATS = 1 << 21
#: Make the regressors with the compiled kernel (:mod:`._lsq_kernel`) when numba runs; False: always
#: with the numpy reference :func:`_basis` (tests compare the two in one process).
KERNEL = True


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


def basis_reference(f: np.ndarray, ks: np.ndarray, tau: np.ndarray) -> np.ndarray:
    """Regressors (b, p, N) at times ``tau``: a row of ones, then cos, sin for each harmonic; one
    cos and one sin of the fundamental per sample, the harmonics by angle addition (k x eps of
    rounding at most).  The plain form, kept as the reference :func:`_basis` is tested against."""
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


def _basis(f: np.ndarray, ks: np.ndarray, sl: slice, n: int, fs_hz: float) -> np.ndarray:
    """Regressors (b, p, L) of samples ``sl`` of an ``n``-sample record: a row of ones, then cos,
    sin for each harmonic: :func:`basis_reference`'s numbers, bit for bit (the same operations in
    the same order), with the harmonics written straight into their rows."""
    nr, length = f.shape[0], sl.stop - sl.start
    basis = np.empty((nr, 1 + 2 * ks.size, length))
    basis[:, 0] = 1.0
    phase = (_TWO_PI * f)[:, None] * times(sl, n, fs_hz)[None, :]
    c1, s1 = np.cos(phase), np.sin(phase)
    rows = {int(k): j for j, k in enumerate(ks)}
    top = int(ks[-1])
    scratch = np.empty((2, 2, nr, length)) if top > 1 else None  # harmonics not fitted, by parity
    tmp = np.empty((2, nr, length)) if top > 1 else None
    c, s = c1, s1
    for k in range(1, top + 1):
        if k > 1:  # c, s <- c c1 - s s1, s c1 + c s1 (the reference's operations, in its order)
            j = rows.get(k)
            cn = basis[:, 1 + 2 * j] if j is not None else scratch[k % 2, 0]
            sn = basis[:, 2 + 2 * j] if j is not None else scratch[k % 2, 1]
            cc, ss = np.multiply(c, c1, out=tmp[0]), np.multiply(s, s1, out=tmp[1])
            np.subtract(cc, ss, out=cn)
            np.multiply(s, c1, out=cc)
            np.multiply(c, s1, out=ss)
            np.add(cc, ss, out=sn)
            c, s = cn, sn
        elif k in rows:
            basis[:, 1 + 2 * rows[k]] = c
            basis[:, 2 + 2 * rows[k]] = s
    return basis


def blocks(n: int, records: int) -> list[slice]:
    """Sample ranges that keep the temporaries of ``records`` records near ``BLOCK`` samples each
    (at least ``MIN_BLOCK`` samples of every record: many short records go in one block)."""
    step = max(MIN_BLOCK, BLOCK // max(records, 1))
    return [slice(s, min(s + step, n)) for s in range(0, n, step)]


def times(sl: slice, n: int, fs_hz: float) -> np.ndarray:
    """Time of samples ``sl`` from the centre of an ``n``-sample record (s); the same numbers,
    element by element, as the whole record's time axis."""
    return (np.arange(sl.start, sl.stop) - (n - 1) / 2.0) / fs_hz


class Bases:
    """The regressors of every block of ``n``-sample records at frequencies ``f`` (b,), made on
    first use and kept when small (at most :data:`KEEP_FLOATS`), with their Gram matrices (the
    same for every channel when no sample is left out): an evaluation's two passes share them,
    and so do later fits at the same frequency (see :func:`bases`).  Read-only."""

    def __init__(self, f: np.ndarray, ks: np.ndarray, n: int, fs_hz: float) -> None:
        self.f, self.ks, self.n, self.fs_hz = f, ks, n, fs_hz
        self.slices = blocks(n, f.shape[0])
        self.floats = f.shape[0] * (1 + 2 * ks.size) * n
        self.kept = self.floats <= KEEP_FLOATS
        self._bases: list[np.ndarray] = []
        self._grams: dict[int, np.ndarray] = {}
        self._rates: dict[int, np.ndarray] = {}
        self._rowk = _lsq_kernel.harmonic_rows(ks)

    def __iter__(self):
        for i, sl in enumerate(self.slices):
            if i < len(self._bases):
                yield sl, self._bases[i]
                continue
            basis = self._make(sl)
            basis.flags.writeable = False
            if self.kept and i == len(self._bases):
                self._bases.append(basis)
            yield sl, basis

    def _make(self, sl: slice) -> np.ndarray:
        """Block ``sl``'s regressors: the compiled kernel's when numba runs (8x faster, equal to
        rounding), else :func:`_basis`."""
        if KERNEL and enabled():
            return _lsq_kernel.basis(np.ascontiguousarray(self.f, dtype=np.float64), self._rowk, int(self.ks[-1]),
                                     1 + 2 * self.ks.size, sl.start, sl.stop, self.n, float(self.fs_hz))
        return _basis(self.f, self.ks, sl, self.n, self.fs_hz)

    def gram(self, i: int, basis: np.ndarray) -> np.ndarray:
        """Gram matrices (b, p, p) of block ``i``'s regressors ``basis`` (as iteration gave them)."""
        g = self._grams.get(i)
        if g is None:
            g = basis @ np.swapaxes(basis, -1, -2)
            if self.kept:
                g.flags.writeable = False
                self._grams[i] = g
        return g

    def two_pi_tau(self, i: int) -> np.ndarray:
        """2 pi times the sample times of block ``i`` (s): d(phase)/df, for the frequency column."""
        r = self._rates.get(i)
        if r is None:
            r = _TWO_PI * times(self.slices[i], self.n, self.fs_hz)
            if self.kept:
                r.flags.writeable = False
                self._rates[i] = r
        return r


_recent = threading.local()  # per thread: the latest Bases, most recent last


def bases(f: np.ndarray, ks: np.ndarray, n: int, fs_hz: float) -> Bases:
    """The :class:`Bases` at frequencies ``f``: the same object as a recent call's when the
    arguments are equal (bit for bit), else a new one, remembered when small.

    The live estimator's fits of one window keep coming back to one frequency: the second
    outlier pass starts where the first ended, the outlier test takes residuals there, and the
    force's fit and the two drive fits start at the frequency the current and flux found.  This
    thread's last :data:`RECENT_FLOATS` floats of regressors are kept (per thread: nothing is
    shared, so no lock)."""
    f = np.array(f, dtype=np.float64)
    key = (f.tobytes(), ks.tobytes(), int(n), float(fs_hz), KERNEL and enabled())  # kernel's or numpy's regressors
    recent: OrderedDict[tuple, Bases] | None = getattr(_recent, "lru", None)
    if recent is None:
        recent = _recent.lru = OrderedDict()
    hit = recent.get(key)
    if hit is not None:
        recent.move_to_end(key)
        return hit
    made = Bases(f, ks, n, fs_hz)
    if made.kept:  # the kept floats are counted as they come and go, not summed over the LRU each call
        recent[key] = made
        _recent.floats = getattr(_recent, "floats", 0) + made.floats
        while _recent.floats > RECENT_FLOATS:
            _recent.floats -= recent.popitem(last=False)[1].floats
    return made


def _block(x: np.ndarray, mask: np.ndarray | None, rows, sl: slice):
    """Samples ``sl`` of records ``rows`` (left-out samples set to 0) and their mask (None: none)."""
    xs = x[rows, :, sl]
    if mask is None:
        return xs, None
    ms = mask[rows, :, sl]
    if not ms.any():
        return xs, None
    return np.where(ms, 0.0, xs), ms


def _gram_solve(gram: np.ndarray, rhs: np.ndarray) -> np.ndarray:
    """x (b, C, p) with ``gram[:, min(c, G-1)] x[:, c] = rhs[:, c]`` for Gram matrices (b, G, p, p):
    by the compiled Cholesky when numba runs (equal to rounding), else (or if a matrix is not
    positive definite) by ``np.linalg.solve``."""
    if KERNEL and enabled():
        x, ok = _lsq_kernel.gram_solve(np.ascontiguousarray(gram, dtype=np.float64),
                                       np.ascontiguousarray(rhs, dtype=np.float64))
        if ok:
            return x
    return np.linalg.solve(gram, rhs[..., None])[..., 0]


def _sum_squares(x: np.ndarray, mask: np.ndarray | None) -> np.ndarray:
    """Sum of squares of each channel (B, C) over the samples kept."""
    out = np.zeros(x.shape[:2])
    for sl in blocks(x.shape[-1], x.shape[0]):
        xs, _ = _block(x, mask, slice(None), sl)
        out += np.einsum("bcn,bcn->bc", xs, xs)
    return out


def _add(total: np.ndarray | None, part: np.ndarray) -> np.ndarray:
    """``total + part``, the first block's ``part`` as it is (``0 + part`` is ``part``: a record of
    one block, every live window but the longest, makes and adds no zeros)."""
    return part if total is None else total + part


def _normal(x, mask, rows, regs: Bases):
    """Normal equations at the frequencies of ``regs`` for records ``rows``, summed block by
    block: Gram matrices (b, 1, p, p), or (b, C, p, p) per channel when samples are left out, and
    the projections (b, C, p) of the data on the regressors."""
    gram = proj = None
    for i, (sl, basis) in enumerate(regs):
        bt = np.swapaxes(basis, -1, -2)
        xs, ms = _block(x, mask, rows, sl)
        if ms is None:
            gram = _add(gram, regs.gram(i, basis)[:, None])
        else:  # a left-out sample weighs nothing in its channel's Gram matrix
            gram = _add(gram, (basis[:, None] * ~ms[:, :, None, :]) @ bt[:, None])
        proj = _add(proj, xs @ bt)
    if gram.shape[1] == 1 and mask is not None and x.shape[1] > 1:
        gram = np.broadcast_to(gram, (gram.shape[0], x.shape[1]) + gram.shape[2:])
    return gram, proj


def _residual_sums(x, mask, rows, regs: Bases, coef, grad: bool):
    """Residual sums of squares (b, C) of the fit ``coef`` at the frequencies of ``regs``, block by block;
    with ``grad`` also what the Gauss-Newton step needs of the frequency column g = d(model)/df:
    g's projections on the regressors (b, C, p), g.g and g.residual (b, C)."""
    ks = regs.ks
    ssq = gb = gg = gr = None
    kc = coef[..., 2::2] * ks  # sine coefficients times k
    ka = coef[..., 1::2] * ks
    for i, (sl, basis) in enumerate(regs):
        xs, ms = _block(x, mask, rows, sl)
        resid = xs - coef @ basis
        if ms is not None:
            resid[ms] = 0.0
        ssq = _add(ssq, np.einsum("bcn,bcn->bc", resid, resid))
        if grad:
            g = regs.two_pi_tau(i) * (kc @ basis[:, 1::2] - ka @ basis[:, 2::2])  # (b, C, L)
            if ms is not None:
                g[ms] = 0.0
            gb = _add(gb, g @ np.swapaxes(basis, -1, -2))
            gg = _add(gg, np.einsum("bcn,bcn->bc", g, g))
            gr = _add(gr, np.einsum("bcn,bcn->bc", g, resid))
    if not grad:
        nr, nc = ssq.shape
        gb, gg, gr = np.zeros((nr, nc, coef.shape[-1])), np.zeros((nr, nc)), np.zeros((nr, nc))
    return ssq, gb, gg, gr


def residual_rows(x: np.ndarray, coef: np.ndarray, freq: np.ndarray, ks: np.ndarray, fs_hz: float) -> np.ndarray:
    """Residuals (R, N) of 1-D records ``x`` (R, N) from fits ``coef`` (R, p) at ``freq`` (R,),
    computed block by block: the only N-sized array is the result."""
    n = x.shape[-1]
    out = np.empty(x.shape)
    for sl, basis in bases(freq, ks, n, fs_hz):
        out[:, sl] = x[:, sl] - (coef[:, None, :] @ basis)[:, 0]
    return out


def solve(
    x: np.ndarray,
    fs_hz: float,
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
    normal equations, then the residuals and the frequency column at the solved coefficients);
    the regressors are made once for both when small (:class:`Bases`), else once per pass, so no
    large N x p regressor matrix ever exists, whatever N."""
    nb, nc, n = x.shape
    if mask is not None and not mask.any():
        mask = None
    ks = np.asarray(harmonics, dtype=np.float64)
    p = 1 + 2 * ks.size
    duration = n / fs_hz
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
        bases_f = bases(freq, ks, n, fs_hz)
        gram, proj = _normal(x, mask, slice(None), bases_f)
        coef = _gram_solve(gram, proj)
        ssq = _residual_sums(x, mask, slice(None), bases_f, coef, grad=False)[0]
        iterations[:] = 1
        converged[:] = True
    else:
        best = np.full(nb, np.inf)
        step = np.zeros(nb)
        f_se = np.zeros(nb)  # standard error of the frequency, for the stopping rule
        dof_min = np.min(dof, axis=-1)
        step_tol = tol / (np.pi * ks[-1] * duration)  # the step that moves the phase at the ends by tol
        active = np.arange(nb)
        for it in range(1, max_iter + 1):
            # the records still searching: all (a slice, so no copies through an index: the usual
            # case, and always for a single record) or some
            rows = slice(None) if active.size == nb else active
            f_try = freq[rows] + step[rows]
            bases_f = bases(f_try, ks, n, fs_hz)
            g_try, proj = _normal(x, mask, rows, bases_f)
            c_try = _gram_solve(g_try, proj)
            s_try, g_b, g_g, g_r = _residual_sums(x, mask, rows, bases_f, c_try, grad=True)
            cost = np.sum(np.log(s_try + floor[rows]), axis=-1)
            iterations[rows] = it

            better = cost <= best[rows]
            if better.all():  # the usual case: no copies through a mask (same values)
                better, keep = slice(None), rows
            else:
                keep = active[better]
            freq[keep] = f_try[better]
            best[keep] = cost[better]
            coef[keep] = c_try[better]
            ssq[keep] = s_try[better]
            gram[keep] = g_try[better]

            # Gauss-Newton step (variable projection) for the records that improved
            g_try, g_b, g_g, g_r = g_try[better], g_b[better], g_g[better], g_r[better]
            bg[keep], gg[keep] = g_b, g_g
            proj_g = np.einsum("bcp,bcp->bc", g_b, _gram_solve(g_try, g_b))
            weight = 1.0 / (ssq[keep] + floor[keep])
            num = np.sum(weight * g_r, axis=-1)
            den = np.sum(weight * np.maximum(g_g - proj_g, 0.0), axis=-1)
            with np.errstate(divide="ignore", invalid="ignore"):
                new_step = np.where(den > 0.0, num / den, 0.0)
                f_se[keep] = 1.0 / np.sqrt(dof_min[keep] * den)
            step[keep] = np.clip(new_step, -max_step, max_step)
            if not isinstance(better, slice):
                step[active[~better]] *= 0.5

            done = np.abs(step[rows]) < np.maximum(step_tol, _STAT_TOL * f_se[rows])
            if not done.any():
                continue
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


def fft_peak_freq(x: np.ndarray, fs_hz: float) -> np.ndarray:
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
    return (i + np.clip(delta, -0.5, 0.5)) * fs_hz / nfft


def grid_start(x: np.ndarray, fs_hz: float, f_c: float, harmonics: tuple[int, ...], half_width_hz: float,
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
    bin_hz = fs_hz / (n * ks[-1])
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
        tau_s = (sl.start - (n - 1) / 2.0) / fs_hz
        for j, k in enumerate(ks):
            key = (xc.shape[-1], j)
            if key not in transforms:
                transforms[key] = CZT(xc.shape[-1], grid.size, w=np.exp(-2j * np.pi * k * spacing / fs_hz),
                                      a=np.exp(2j * np.pi * k * grid[0] / fs_hz))
            acc[:, j] += transforms[key](xc) * np.exp(-2j * np.pi * k * grid * tau_s)
    power = np.sum((acc.real ** 2 + acc.imag ** 2).reshape(nb, -1, grid.size), axis=1)  # (B, grid)
    return grid[np.argmax(power, axis=-1)]
