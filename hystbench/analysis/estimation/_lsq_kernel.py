"""Compiled twin of :func:`._lsq._basis`: the regressors of a block of samples (private).

The numpy path takes a cos and a sin per sample (two transcendental calls, ~40 ns) and makes the
harmonics by whole-array angle addition (a dozen temporaries); on the live estimator that was the
largest part of the sine fits' time, as each window brings ~3.4 new trial frequencies.  This
kernel takes the fundamental's cos and sin exactly (``math.cos``/``math.sin``) at every
``CHUNK``-th sample and adds the angle of the m samples since (a table of ``CHUNK`` cos and sin
per record) in between: two roundings, no drift along the chunk; the harmonics by angle addition in
:func:`._lsq.basis_reference`'s order, written straight into their rows.  The numbers equal the
numpy path's to rounding, not bit for bit (tests/analysis/estimation/test_lsq_kernel.py).

A kernel that also took the sums (Gram matrix, projections, residuals) in the same pass, without
keeping the regressors, was measured and dropped: scalar code without fastmath is ~1 flop a
cycle, so its two passes (1.2 ms for a 25 000-sample, two-channel window) cost more than the
kept regressors reduced by BLAS (~0.15 ms per evaluation at a frequency seen before).
"""

from __future__ import annotations

import math

import numpy as np

from hystbench.jit import njit

CHUNK = 64  # samples per exact re-anchoring of the fundamental's cos and sin
_TWO_PI = 2.0 * math.pi


@njit(cache=True, nogil=True)
def basis(f: np.ndarray, rowk: np.ndarray, kmax: int, p: int, start: int, stop: int, n: int,
          fs_hz: float) -> np.ndarray:
    """Regressors (b, p, stop - start) of samples ``start .. stop`` of ``n``-sample records at
    frequencies ``f`` (b,): a row of ones, then cos, sin of each fitted harmonic k (``rowk[k]`` its
    index, -1 if not fitted) of ``2 pi k f tau``, tau the time from the record's centre."""
    nr = f.shape[0]
    length = stop - start
    out = np.empty((nr, p, length))
    centre = (n - 1) / 2.0
    ct = np.empty(CHUNK)  # cos, sin of m samples' angle, m < CHUNK
    st = np.empty(CHUNK)
    for r in range(nr):
        w = _TWO_PI * f[r]
        dphi = w / fs_hz
        for m in range(CHUNK):
            ct[m] = math.cos(m * dphi)
            st[m] = math.sin(m * dphi)
        ca = 1.0
        sa = 0.0
        for i in range(length):
            m = i % CHUNK
            if m == 0:  # exact anchor: the numpy path's phase of this sample
                phase = w * ((start + i - centre) / fs_hz)
                ca = math.cos(phase)
                sa = math.sin(phase)
            c1 = ca * ct[m] - sa * st[m]  # angle addition from the anchor: ~2 roundings, no drift
            s1 = sa * ct[m] + ca * st[m]
            out[r, 0, i] = 1.0
            c = c1
            s = s1
            for k in range(1, kmax + 1):
                if k > 1:
                    c, s = c * c1 - s * s1, s * c1 + c * s1
                j = rowk[k]
                if j >= 0:
                    out[r, 1 + 2 * j, i] = c
                    out[r, 2 + 2 * j, i] = s
    return out


def harmonic_rows(ks: np.ndarray) -> np.ndarray:
    """``rowk[k]``: the index of harmonic ``k`` in ``ks`` (-1 when not fitted), k = 0 .. max(ks)."""
    rowk = np.full(int(ks[-1]) + 1, -1, dtype=np.int64)
    for j, k in enumerate(ks):
        rowk[int(k)] = j
    return rowk


@njit(cache=True, nogil=True)
def gram_solve(gram: np.ndarray, rhs: np.ndarray) -> tuple[np.ndarray, bool]:
    """Solutions (b, C, p) of ``gram[:, min(c, G-1)] x = rhs[:, c]`` for Gram matrices (b, G, p, p)
    (G = 1: shared by the channels) by Cholesky, and whether every matrix was positive definite
    (if not, the caller takes numpy's LU, which says what is wrong).  ``np.linalg.solve`` on a
    9 x 9 costs ~24 us of call and checks; this ~1 us."""
    nb, ng, p = gram.shape[0], gram.shape[1], gram.shape[2]
    nc = rhs.shape[1]
    out = np.empty((nb, nc, p))
    low = np.empty((p, p))
    y = np.empty(p)
    for r in range(nb):
        for g in range(ng):
            for j in range(p):  # low low^T = gram[r, g]
                d = gram[r, g, j, j]
                for m in range(j):
                    d -= low[j, m] * low[j, m]
                if not d > 0.0:
                    return out, False
                d = math.sqrt(d)
                low[j, j] = d
                for i in range(j + 1, p):
                    s = gram[r, g, i, j]
                    for m in range(j):
                        s -= low[i, m] * low[j, m]
                    low[i, j] = s / d
            for c in range(nc):
                if ng > 1 and c != g:
                    continue
                for i in range(p):  # forward, then back substitution
                    s = rhs[r, c, i]
                    for m in range(i):
                        s -= low[i, m] * y[m]
                    y[i] = s / low[i, i]
                for i in range(p - 1, -1, -1):
                    s = y[i]
                    for m in range(i + 1, p):
                        s -= low[m, i] * out[r, c, m]
                    out[r, c, i] = s / low[i, i]
    return out, True
