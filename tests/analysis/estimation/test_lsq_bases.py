"""The fit's regressors made once per frequency (issue 14) give the numbers of making them afresh
on every pass, bit for bit.

Before, each Gauss-Newton evaluation made the cos/sin regressors twice (normal equations, then
residuals), and every later fit at the same frequency (the second outlier pass, the outlier test,
the force's and the drives' fits in the live estimator) made them again.  Now :func:`_lsq.bases`
keeps a thread's recent ones.  The reference here is the former computation written out: per block,
:func:`_lsq.basis_reference` (the former ``_basis``, kept) and the former sums over it, and a fit
in a fresh thread (nothing kept) against one in a thread that has fitted other records first.
"""

from __future__ import annotations

import numpy as np
import pytest

from hystbench.analysis.estimation import _lsq, phase_delay, sine_fit
from hystbench.jit import enabled

from .conftest import in_fresh_thread

FS = 100_000.0


def _record(n: int, seed: int, f: float = 40.0013, chans: int = 2, batch: int = 1) -> np.ndarray:
    """(batch, chans, n) sines with harmonics, DC and noise at ~60 dB, a glitch in the last channel."""
    rng = np.random.default_rng(seed)
    w = 2 * np.pi * f * np.arange(n) / FS
    phi = rng.uniform(-np.pi, np.pi, (batch, chans, 1))
    x = 0.7 * np.cos(w + phi) + 0.05 * np.cos(2 * w + 2 * phi + 0.4) + 0.01 * np.cos(3 * w) + 0.1
    x += rng.normal(0.0, 1e-3, x.shape)
    x[:, -1, n // 3] += 5.0
    return x


@pytest.mark.parametrize("ks", [(1,), (2,), (1, 2, 3, 4), (1, 3), (2, 5)])
@pytest.mark.parametrize("seed", range(4))
def test_basis_is_the_reference_bit_for_bit(ks, seed):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(300, 40_000))
    f = rng.uniform(10.0, 0.4 * FS / max(ks), int(rng.integers(1, 4)))
    kf = np.asarray(ks, dtype=np.float64)
    for sl in _lsq.blocks(n, f.size):
        got = _lsq._basis(f, kf, sl, n, FS)
        want = _lsq.basis_reference(f, kf, _lsq.times(sl, n, FS))
        assert got.shape == want.shape == (f.size, 1 + 2 * len(ks), sl.stop - sl.start)
        assert np.array_equal(got, want)


def _reference_evaluation(x, mask, f, ks, fs, coef):
    """The former two passes at frequencies ``f``, each making its regressors per block."""
    n, nc, nr = x.shape[-1], x.shape[1], f.shape[0]
    p = 1 + 2 * ks.size
    gram = np.zeros((nr, 1 if mask is None else nc, p, p))
    proj = np.zeros((nr, nc, p))
    for sl in _lsq.blocks(n, nr):
        basis = _lsq.basis_reference(f, ks, _lsq.times(sl, n, fs))
        bt = np.swapaxes(basis, -1, -2)
        xs, ms = _lsq._block(x, mask, slice(None), sl)
        gram += (basis @ bt)[:, None] if ms is None else (basis[:, None] * ~ms[:, :, None, :]) @ bt[:, None]
        proj += xs @ bt
    ssq, gb, gg, gr = np.zeros((nr, nc)), np.zeros((nr, nc, p)), np.zeros((nr, nc)), np.zeros((nr, nc))
    kc, ka = coef[..., 2::2] * ks, coef[..., 1::2] * ks
    for sl in _lsq.blocks(n, nr):
        tau = _lsq.times(sl, n, fs)
        basis = _lsq.basis_reference(f, ks, tau)
        xs, ms = _lsq._block(x, mask, slice(None), sl)
        resid = xs - coef @ basis
        g = 2.0 * np.pi * tau * (kc @ basis[:, 1::2] - ka @ basis[:, 2::2])
        if ms is not None:
            resid[ms] = 0.0
            g[ms] = 0.0
        ssq += np.einsum("bcn,bcn->bc", resid, resid)
        gb += g @ np.swapaxes(basis, -1, -2)
        gg += np.einsum("bcn,bcn->bc", g, g)
        gr += np.einsum("bcn,bcn->bc", g, resid)
    return gram, proj, ssq, gb, gg, gr


@pytest.mark.parametrize("masked", [False, True])
@pytest.mark.parametrize("n,batch", [(25_000, 1), (40_000, 1), (2_000, 5)])
def test_one_evaluation_is_the_former_one_bit_for_bit(n, batch, masked, monkeypatch):
    # the numpy path (the compiled regressors equal it to rounding: test_lsq_kernel.py)
    monkeypatch.setattr(_lsq, "KERNEL", False)
    x = _record(n, seed=n + batch, batch=batch, chans=3)
    mask = np.zeros(x.shape, bool) if masked else None
    if masked:
        mask[:, -1, n // 3] = mask[:, 0, 7] = True
    ks = np.array([1.0, 2.0, 3.0, 4.0])
    f = 40.0013 + np.arange(batch) * 1e-3
    coef = np.random.default_rng(1).normal(size=(batch, 3, 9))
    regs = _lsq.bases(f, ks, n, FS)
    got = _lsq._normal(x, mask, slice(None), regs) + _lsq._residual_sums(x, mask, slice(None), regs, coef, True)
    again = _lsq._normal(x, mask, slice(None), regs) + _lsq._residual_sums(x, mask, slice(None), regs, coef, True)
    want = _reference_evaluation(x, mask, f, ks, FS, coef)
    for g, a, w in zip(got, again, want):
        assert np.array_equal(g, w)
        assert np.array_equal(a, w)  # the kept regressors (and Gram matrices) are the same numbers


def _fits(x: np.ndarray):
    """What the live estimator does to a window: a joint fit with outliers, a fit at the frequency
    found, a joint fit of other channels starting there."""
    d = phase_delay(x[0, 0], x[0, 1], FS, 40.0, harmonics=(1, 2, 3, 4))
    s = sine_fit(x[0, 1], FS, float(d.frequency_hz), harmonics=(1, 2, 3, 4), fit_freq=False)
    e = phase_delay(x[0, 1], x[0, 0] ** 2, FS, float(d.frequency_hz), harmonic=2, harmonics=(1, 2, 3, 4),
                    outlier_sigmas=None)
    return [np.asarray(v) for v in (d.delay_s, d.delay_se_s, d.frequency_hz, d.frequency_se_hz, d.x.amplitude,
                                    d.y.phase_rad, d.y.outliers, d.x.iterations, s.amplitude, s.phase_se_rad,
                                    s.noise_std, e.delay_s, e.delay_se_s, e.frequency_hz, e.y.noise_std)]


@pytest.mark.parametrize("n", [25_000, 200_000])
def test_fits_do_not_depend_on_what_the_thread_kept(n):
    """A window's fits in a fresh thread (every regressor made afresh) and after fits of other
    records of the same length and frequency (regressors kept and reused) agree bit for bit; the
    200 000-sample record is too long to keep (made again on each pass)."""
    x = _record(n, seed=3)
    cold = in_fresh_thread(lambda: _fits(x))

    def warm():
        for seed in (4, 5):
            _fits(_record(n, seed=seed))
        first = _fits(x)
        return first, _fits(x)

    first, second = in_fresh_thread(warm)
    assert cold[6].tolist() == [n // 3]  # the glitch was found and left out
    for c, a, b in zip(cold, first, second):
        assert np.array_equal(c, a) and np.array_equal(c, b)


def test_kept_regressors_are_shared_bounded_and_read_only():
    def run():
        ks = np.array([1.0, 2.0, 3.0, 4.0])
        f = np.array([40.0013])
        a, b = _lsq.bases(f, ks, 25_000, FS), _lsq.bases(f.copy(), ks, 25_000, FS)
        other = [_lsq.bases(f, ks, 25_001, FS), _lsq.bases(f, ks, 25_000, 2 * FS), _lsq.bases(f, ks[:2], 25_000, FS)]
        basis = next(iter(a))[1]
        with pytest.raises(ValueError):
            basis[0, 0, 0] = 1.0
        for i in range(40):  # far more than fit in RECENT_FLOATS: the oldest go
            list(_lsq.bases(f + i, ks, 25_000, FS))
        kept = sum(r.floats for r in _lsq._recent.lru.values())
        c = _lsq.bases(f, ks, 25_000, FS)
        return a is b, all(o is not a for o in other), kept, c is a, next(iter(c))[1], basis

    same, distinct, kept, still, basis, first = in_fresh_thread(run)
    assert same and distinct
    assert 0 < kept <= _lsq.RECENT_FLOATS
    assert not still  # evicted long ago, made again: the same numbers
    assert np.array_equal(basis, first)
    # (bit for bit on the numpy path; the compiled one's equal it to rounding, test_lsq_kernel.py)
    np.testing.assert_allclose(basis, _lsq.basis_reference(np.array([40.0013]), np.array([1.0, 2.0, 3.0, 4.0]),
                                                           _lsq.times(_lsq.blocks(25_000, 1)[0], 25_000, FS)),
                               rtol=0, atol=1e-12 if _lsq.KERNEL and enabled() else 0.0)
