"""Compiled (numba) kernel of the Preisach iron's B-driven branch table.

:meth:`~hystbench.physics.hysteresis.PreisachHysteresis._build_inverse` inverts every ascending
branch H(B - B_r) from a reversal; its numpy form is one ``np.interp`` and a dozen temporaries per
row, which is numpy's per-call overhead, not arithmetic, at the fitting tables' 201 rows of 1001
nodes (8.6 ms a table, half of a ``model fit``: each residual of the Preisach fit builds one).  One
pass per row here: the branch, its running maximum and the merge with the sorted targets, with the
same operations in the same order as the numpy code beside it (the reference and the fallback,
``HYSTBENCH_JIT=0``), so the tables agree to the ulps of ``sinh``.

Imported only when ``hystbench.jit.enabled()``; callers pass C-contiguous float64 arrays.
"""

from __future__ import annotations

import math

import numpy as np

from ..jit import njit

__all__ = ["ascending_branches"]


@njit(cache=True, nogil=True)
def ascending_branches(rows: np.ndarray, db: np.ndarray, x: np.ndarray, K: np.ndarray, G: np.ndarray,
                       F: np.ndarray, brev: np.ndarray, h_last: float, h0: float, s_end: float,
                       out: np.ndarray) -> None:
    """``out[r, c]`` = H at B - B_r = ``db[c]`` on the ascending branch from fine node ``rows[r]``:
    g = 2 (K - K_j - G_j (F - F_j)) + B_rev - B_rev_j made non-decreasing, x(db) by ``np.interp``'s
    rule (the last node with g <= db; exact at a node), H = h0 sinh(x), or the straight continuation
    beyond the branch's end.  ``out`` has ``rows.size`` rows and at least ``db.size`` columns."""
    n = x.size
    m = db.size
    g = np.empty(n)
    for r in range(rows.size):
        j = rows[r]
        kj, gj, fj, bj = K[j], G[j], F[j], brev[j]
        top = -math.inf
        for c in range(j, n):
            e = (K[c] - kj) - gj * (F[c] - fj)
            v = (2.0 * e + brev[c]) - bj
            if v > top:
                top = v
            g[c] = top
        i = j  # the last node with g <= the target (targets ascend, so it only moves on)
        for k in range(m):
            d = db[k]
            if d > top:
                out[r, k] = h_last + (d - top) / s_end
                continue
            while i + 1 < n and g[i + 1] <= d:
                i += 1
            if i == n - 1 or g[i] == d:
                xs = x[i]
            else:
                slope = (x[i + 1] - x[i]) / (g[i + 1] - g[i])
                xs = slope * (d - g[i]) + x[i]
            out[r, k] = h0 * math.sinh(xs)
