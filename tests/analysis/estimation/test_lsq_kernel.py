"""The compiled regressors (:mod:`hystbench.analysis.estimation._lsq_kernel`) against the numpy
reference, in one process: the regressors themselves against cos/sin taken directly, the normal
equations and residual sums built from them against numpy's, and whole estimates of the method on
simulated-rig windows (equal to rounding: relative 1e-8 or 1e-3 of their standard error)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from hystbench.acquisition.sources import RigSource
from hystbench.analysis.estimation import _lsq, _lsq_kernel
from hystbench.analysis.method import measure_window
from hystbench.jit import enabled
from hystbench.sim_backend.rig import SimulatedRig

pytestmark = pytest.mark.skipif(not enabled(), reason="numba missing or HYSTBENCH_JIT=0: no kernel to compare")

FS = 100_000.0


def _bases(compiled: bool, f, ks, n) -> _lsq.Bases:
    """Every block's regressors, made by the kernel or by numpy (a new Bases: no cache shared)."""
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(_lsq, "KERNEL", compiled)
        regs = _lsq.Bases(np.asarray(f, dtype=np.float64), ks, n, FS)
        list(regs)  # made now, and kept (small): later passes reuse these
    assert regs.kept
    return regs


def _close(got: np.ndarray, want: np.ndarray, scale, rel: float = 1e-9) -> None:
    """Equal within ``rel`` of ``scale``, the size of the sum's terms (Cauchy-Schwarz: |a.b| <=
    |a| |b|): entries that cancel to ~0 are rounding summed in either order, so a per-entry
    relative test would measure noise."""
    scale = np.broadcast_to(np.asarray(scale, dtype=np.float64), want.shape)
    assert np.all(np.abs(got - want) <= rel * scale + np.finfo(np.float64).tiny), np.max(np.abs(got - want) / scale)


record = st.tuples(
    st.integers(1, 3),  # records
    st.integers(1, 3),  # channels
    st.integers(3, 3000),  # samples
    st.lists(st.integers(1, 7), min_size=1, max_size=4, unique=True).map(sorted),  # harmonics
    st.floats(0.05, 0.45),  # highest harmonic's frequency / fs ... times the cycle fraction below
    st.sampled_from([0.0, 1e-6, 1.0, 1e3]),  # noise level
    st.sampled_from([0.0, 0.01, 0.3]),  # share of samples left out
    st.integers(0, 2**32 - 1),
)


@settings(max_examples=60, deadline=None)
@given(record)
def test_regressors_are_cos_and_sin_of_each_harmonic(case):
    nb, _, n, harmonics, frac, _, _, seed = case
    rng = np.random.default_rng(seed)
    ks = np.asarray(harmonics, dtype=np.float64)
    f = rng.uniform(0.5, 1.0, nb) * frac * FS / ks[-1]
    regs = _bases(True, f, ks, n)
    tau = (np.arange(n) - (n - 1) / 2.0) / FS  # independent: each harmonic's angle taken directly
    for sl, basis in regs:
        t = tau[sl]
        assert np.all(basis[:, 0] == 1.0)
        for j, k in enumerate(ks):
            angle = 2.0 * np.pi * k * f[:, None] * t[None, :]
            np.testing.assert_allclose(basis[:, 1 + 2 * j], np.cos(angle), rtol=0, atol=1e-11)
            np.testing.assert_allclose(basis[:, 2 + 2 * j], np.sin(angle), rtol=0, atol=1e-11)


@settings(max_examples=60, deadline=None)
@given(record)
def test_normal_equations_and_residual_sums_equal_numpys(case):
    nb, nc, n, harmonics, frac, noise, share, seed = case
    rng = np.random.default_rng(seed)
    ks = np.asarray(harmonics, dtype=np.float64)
    p = 1 + 2 * ks.size
    f = rng.uniform(0.5, 1.0, nb) * frac * FS / ks[-1]
    coef = rng.normal(size=(nb, nc, p))
    tau = (np.arange(n) - (n - 1) / 2.0) / FS
    phase = 2.0 * np.pi * f[:, None, None] * tau
    x = coef[..., :1] + sum(coef[..., 1 + 2 * j, None] * np.cos(k * phase)
                            + coef[..., 2 + 2 * j, None] * np.sin(k * phase)
                            for j, k in enumerate(ks))
    x = x + noise * rng.normal(size=x.shape)
    mask = rng.random(x.shape) < share if share else None
    if mask is not None:
        mask[..., : p + 2] = False  # some samples kept in every channel
        x[mask] = np.nan  # a left-out sample's value must never be read
    rows = slice(None) if nb == 1 else np.arange(nb)[::-1].copy()  # records in another order too
    fr = f if isinstance(rows, slice) else f[rows]
    cf = coef if isinstance(rows, slice) else coef[rows]
    got_regs, ref_regs = _bases(True, fr, ks, n), _bases(False, fr, ks, n)
    got, ref = _lsq._normal(x, mask, rows, got_regs), _lsq._normal(x, mask, rows, ref_regs)
    xs = x[rows] if mask is None else np.where(mask, 0.0, x)[rows]
    norm_x = np.sqrt(np.sum(xs * xs, axis=-1))  # (b, C); each regressor's norm is at most sqrt(n)
    _close(got[0], ref[0], n)
    _close(got[1], ref[1], norm_x[..., None] * math.sqrt(n))
    got = _lsq._residual_sums(x, mask, rows, got_regs, cf * 1.001, True)
    ref = _lsq._residual_sums(x, mask, rows, ref_regs, cf * 1.001, True)
    ssq, gb, gg, gr = ref
    _close(got[0], ssq, ssq)
    _close(got[2], gg, gg)
    _close(got[1], gb, np.sqrt(gg * n)[..., None])
    _close(got[3], gr, np.sqrt(gg * ssq))


def _windows(rig: str, frequencies: tuple[float, ...]) -> tuple[bool, list[dict[str, np.ndarray]]]:
    """Ten-period windows of a simulated rig's current, flux and force at each frequency."""
    sim = SimulatedRig(rig, fs_hz=FS, seed=3)
    src = RigSource(sim, block_samples=5000, pace="max")
    src.set_output(True)
    blocks = src.blocks()
    out = []
    for f in frequencies:
        src.set_excitation(frequency_hz=f)
        n = int(round(10 * FS / f))
        got = []
        while sum(b.n for b in got) < 0.3 * FS + n:  # settled, then a window
            got.append(next(blocks))
        chans = {c: np.concatenate([np.asarray(b.channels[c], dtype=np.float64) for b in got])[-n:]
                 for c in ("current_A", "flux_Wb", "force_N")}
        out.append(chans)
    src.close()
    return bool(src.metadata().get("magnet", rig.endswith("_pm"))), out


@pytest.mark.parametrize("rig, frequencies, spikes", [("ecore_pm", (80.0, 320.0), False), ("ecore_pm", (160.0,), True),
                                                      ("ecore", (120.0,), False)])
def test_method_estimates_equal_numpys_to_rounding(monkeypatch, rig, frequencies, spikes):
    magnet, windows = _windows(rig, frequencies)
    for f, chans in zip(frequencies, windows):
        if spikes:  # outliers: the fits then run with samples left out
            chans = {c: x.copy() for c, x in chans.items()}
            for c, x in chans.items():
                x[[101, 2002, 3003]] += 50.0 * np.std(x)
        res = {}
        for compiled in (True, False):
            monkeypatch.setattr(_lsq, "KERNEL", compiled)
            res[compiled] = measure_window(chans, FS, f, magnet=magnet)
        got, ref = res[True], res[False]
        if spikes:
            assert any(ref.outliers.values()) and got.outliers == ref.outliers
        assert math.isclose(got.frequency_hz, ref.frequency_hz,
                            abs_tol=max(1e-8 * abs(ref.frequency_hz), 1e-3 * ref.frequency_std_hz))
        for name, d in ref.delays_s.items():
            tol = max(1e-8 * abs(d), 1e-3 * ref.delays_std_s[name])
            assert abs(got.delays_s[name] - d) <= tol, (name, got.delays_s[name], d, tol)
            assert math.isclose(got.delays_std_s[name], ref.delays_std_s[name], rel_tol=1e-6)


def test_harmonic_rows_index_each_fitted_harmonic():
    assert _lsq_kernel.harmonic_rows(np.array([2.0, 5.0])).tolist() == [-1, -1, 0, -1, -1, 1]


@settings(max_examples=40, deadline=None)
@given(st.integers(1, 3), st.integers(1, 3), st.booleans(), st.integers(1, 15), st.integers(0, 2**32 - 1))
def test_gram_solve_equals_numpys(nb, nc, per_channel, p, seed):
    """The compiled Cholesky solve against LAPACK's LU, for Gram matrices shared by the channels or
    one per channel (the masked case)."""
    rng = np.random.default_rng(seed)
    a = rng.normal(size=(nb, nc if per_channel else 1, p, 3 * p + 5))
    gram = a @ np.swapaxes(a, -1, -2)
    rhs = rng.normal(size=(nb, nc, p))
    want = np.linalg.solve(gram, rhs[..., None])[..., 0]
    got, ok = _lsq_kernel.gram_solve(gram, rhs)
    assert ok
    np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-9 * float(np.max(np.abs(want))))
    # ... and back through the equations themselves: gram x = rhs
    idx = np.minimum(np.arange(nc), gram.shape[1] - 1)
    np.testing.assert_allclose(np.einsum("bcij,bcj->bci", gram[:, idx], got), rhs,
                               rtol=0, atol=1e-8 * np.max(np.abs(rhs)))


def test_a_singular_gram_matrix_falls_back_to_numpys_error():
    """A Gram matrix that is not positive definite (a regressor all zero) is not solved by the
    kernel; numpy's solve then says so, as before."""
    gram = np.eye(3)[None, None].copy()
    gram[0, 0, 2, 2] = 0.0
    assert not _lsq_kernel.gram_solve(gram, np.ones((1, 2, 3)))[1]
    with pytest.raises(np.linalg.LinAlgError):
        _lsq._gram_solve(gram, np.ones((1, 2, 3)))
