"""Compiled (numba) kernels of the Preisach iron: its B-driven branch table, and its field sample by
sample.  The numpy code of :mod:`hystbench.physics.hysteresis` is the reference and the fallback
(``HYSTBENCH_JIT=0``); each kernel uses the same operations in the same order, so they agree to the
ulps of ``sinh``/``asinh``.

- :func:`ascending_branches`: :meth:`PreisachHysteresis._build_inverse` inverts every ascending branch
  H(B - B_r) from a reversal; its numpy form is one ``np.interp`` and a dozen temporaries per row,
  which is numpy's per-call overhead, not arithmetic, at the fitting tables' 201 rows of 1001 nodes
  (8.6 ms a table, half of a ``model fit``: each residual of the Preisach fit builds one).
- :func:`field_along` (:func:`iron_field`): ``PreisachHysteresis.field`` along a trajectory.  The numpy
  field works per branch (a Python step per reversal), which dominates on short trajectories with
  many minor loops: the fits that evaluate the iron thousands of times over one period or one
  measured row (the compensator's model fit, the material fit, the waveform diagnosis).  Its helpers
  are what the E-core's kernels (:mod:`hystbench.sim_backend.actuators.ecore_kernel`) inline into
  their passes; numba's on-disk cache of that module is keyed on its own file only, so it drops its
  cache when this file changes (:func:`hystbench.jit.drop_stale_cache`).

The field's tables come from ``PreisachHysteresis.kernel_tables()``: ``tabs`` = (h0, x0, 1/dx_rows, nrow,
ncol, h_max, s_end, dmax, kcol, virgin step, anhysteretic step, small-signal dH/dB, the flattest
branch's dH/dB, MIN_REACH), ``psi`` the branch table, ``virg`` the virgin curve, ``an`` the anhysteretic
one.  Callers pass C-contiguous float64 arrays.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from ..jit import enabled, njit
from .hysteresis import HysteresisState

if TYPE_CHECKING:
    from .hysteresis import PreisachHysteresis

#: a branch's constants (:func:`branch_consts`): c1, row fraction, row base, edge, shift, the miss at the
#: turning point it returns to, that target, s / reach
Branch = tuple[float, float, int, bool, float, float, float, float]

__all__ = ["ascending_branches", "NO_BRANCH", "read_uniform", "table_at", "branch_consts", "branch_at", "start_state",
           "iron_at", "iron_field", "field_along"]


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


@njit(cache=True, nogil=True, inline="always")
def read_uniform(step: float, t: np.ndarray, s_end: float, b: float) -> float:
    """PreisachHysteresis._read_uniform at one sample: odd table H(|B|), straight beyond its end."""
    a = abs(b) / step
    ac = min(a, t.size - 1.0)
    i = min(int(ac), t.size - 2)
    v = t[i] + (ac - i) * (t[i + 1] - t[i]) + (a - ac) * step / s_end
    if b > 0.0:
        return v
    if b < 0.0:
        return -v
    return 0.0 * v


@njit(cache=True, nogil=True, inline="always")
def table_at(s: float, c1: float, tr: float, base: int, edge: bool, shift: float, b: float, psi: np.ndarray,
             ncol: int, dmax: float, kcol: float, s_end: float) -> float:
    """H on the ascending-frame branch at B = b as the table gives it: the sqrt-warped column,
    bilinear in the table."""
    d = s * b - c1
    neg = min(d, 0.0)
    d = max(d, 0.0)
    extra = 0.0
    if d > dmax:
        extra = (d - dmax) / s_end
    d = math.sqrt(d) * kcol
    ik = min(int(d), ncol - 2)  # clipping only matters past dmax (the spare column covers the rest)
    d = min(d, ncol - 2.0)
    d -= ik
    ik += base
    v0 = psi[ik]
    v1 = psi[ik + 1]
    w1 = psi[ik + 1 + ncol]
    w0 = psi[ik + ncol]
    w0 = w0 + (w1 - w0) * d
    v0 = v0 + (v1 - v0) * d
    v0 = v0 + (w0 - v0) * tr
    if edge:
        v0 += neg / s_end + shift
    v0 += extra
    return v0 * s


@njit(cache=True, nogil=True)
def branch_consts(s: float, m: int, tin: np.ndarray, tout: np.ndarray, tabs: np.ndarray, psi: np.ndarray,
                  virg: np.ndarray) -> Branch:
    """The constants of the branch from turning point ``tin[m - 1]`` in direction ``s`` (``field``'s
    ``branch``: c1, row fraction, row base, edge, shift; then hysteresis._closure's miss at the
    turning point it returns to, that target and the reach); a real call: it runs once per reversal
    or wipe-out, not per sample."""
    h0, x0, inv_dx, nrow, ncol, hmax = tabs[0], tabs[1], tabs[2], int(tabs[3]), int(tabs[4]), tabs[5]
    s_end, dmax, kcol, v_step = tabs[6], tabs[7], tabs[8], tabs[9]
    b_r, h_r = tin[m - 1], tout[m - 1]
    hs = s * h_r
    c1 = s * b_r
    edge = False
    shift = 0.0
    if hs < -hmax or hs > hmax:
        edge = True
        if hs < -hmax:
            c1 = c1 + s_end * (-hmax - hs)
        shift = max(hs - hmax, 0.0)
        hs = min(max(hs, -hmax), hmax)
    fr = (math.asinh(hs / h0) - x0) * inv_dx
    jr = min(int(fr), nrow - 2)
    tr, base = fr - jr, jr * ncol
    if m > 1:
        t_in, t_out = tin[m - 2], tout[m - 2]
    else:  # a single turn returns to its mirror on the virgin curve
        t_in = -b_r
        t_out = read_uniform(v_step, virg, s_end, t_in)
    at_t = table_at(s, c1, tr, base, edge, shift, t_in, psi, ncol, dmax, kcol, s_end)
    miss = t_out - at_t
    twice = 2.0 * abs(miss)
    wide = min(s * (t_in - b_r), twice / tabs[12])
    chord = s * (at_t - table_at(s, c1, tr, base, edge, shift, t_in - s * wide, psi, ncol, dmax, kcol, s_end))
    reach = min(wide, twice * wide / chord) if chord > 0.0 else wide
    return c1, tr, base, edge, shift, miss, t_in, s / reach if reach > tabs[13] else 0.0  # tabs[13]: MIN_REACH


@njit(cache=True, nogil=True, inline="always")
def branch_at(s: float, br: Branch, b: float, psi: np.ndarray, tabs: np.ndarray) -> float:
    """H on the branch ``br`` (:func:`branch_consts`) at B = b: the table's value, plus its miss
    over the last reach of the way to the turning point it returns to (hysteresis._closed)."""
    c1, tr, base, edge, shift, miss, target, per_reach = br  # per_reach: s / reach (0: no reach)
    y = table_at(s, c1, tr, base, edge, shift, b, psi, int(tabs[4]), tabs[7], tabs[8], tabs[6])
    way = 1.0 - (target - b) * per_reach if per_reach != 0.0 else 0.0
    way = min(max(way, 0.0), 1.0)
    return y + way * miss


#: the branch constants before any branch is known (the virgin curve: never read)
NO_BRANCH = (0.0, 0.0, 0, False, 0.0, 0.0, 0.0, 0.0)


@njit(cache=True, nogil=True, inline="always")
def start_state(c_in: np.ndarray, c_out: np.ndarray, state0: np.ndarray, tin: np.ndarray, tout: np.ndarray,
                tabs: np.ndarray, psi: np.ndarray, virg: np.ndarray) -> tuple[int, float, float, float, float, Branch]:
    """A committed state unpacked for the sample loops: its turning points copied into tin/tout, and
    (turns, B, H, direction, branch direction, the branch's constants; NO_BRANCH on the virgin curve)."""
    nst = c_in.size
    for i in range(nst):
        tin[i] = c_in[i]
        tout[i] = c_out[i]
    d = state0[2]
    br = NO_BRANCH
    if nst > 0:
        br = branch_consts(d, nst, tin, tout, tabs, psi, virg)
    return nst, state0[0], state0[1], d, d, br


@njit(cache=True, nogil=True, inline="always")
def iron_at(b: float, u_prev: float, y_prev: float, d: float, nst: int, tin: np.ndarray, tout: np.ndarray, s: float,
            br: Branch, tabs: np.ndarray, psi: np.ndarray, virg: np.ndarray, an: np.ndarray, irreversible: bool,
            saturation: bool) -> tuple[float, float, float, int, float, Branch]:
    """The iron's H at input ``b`` for the next sample, from the committed state (the turning-point
    rule of ``hysteresis._plan``, one sample, as the E-core's passes apply it), committing nothing: a reversal writes ``u_prev`` at
    ``tin[nst]``, beyond the committed stack.  Returns (H of the full model, H as the effects ask,
    direction, turning points, branch direction and the branch constants)."""
    s_end, v_step, a_step, ss = tabs[6], tabs[9], tabs[10], tabs[11]
    diff = b - u_prev
    ds = 1.0 if diff > 0.0 else (-1.0 if diff < 0.0 else d)
    m = nst
    reset = False
    if ds != d:
        if d != 0.0:
            tin[m] = u_prev
            tout[m] = y_prev
            m += 1
        reset = True
    while m > 0:
        thr = tin[m - 2] if m > 1 else -tin[0]
        if (b < thr) if ds > 0.0 else (b > thr):
            break
        m = max(m - 2, 0)
        reset = True
    if reset:
        s = ds
        if m > 0:
            br = branch_consts(s, m, tin, tout, tabs, psi, virg)
    if m == 0:
        y = read_uniform(v_step, virg, s_end, b)
    else:
        y = branch_at(s, br, b, psi, tabs)
    h = y
    if not (irreversible and saturation):
        h_an = read_uniform(a_step, an, s_end, b)
        single = h_an if saturation else ss * b
        h = single + (y - h_an) if irreversible else single
    return y, h, ds, m, s, br


@njit(cache=True, nogil=True)
def iron_field(b: np.ndarray, c_in: np.ndarray, c_out: np.ndarray, state0: np.ndarray, tin: np.ndarray,
               tout: np.ndarray, end: np.ndarray, tabs: np.ndarray, psi: np.ndarray, virg: np.ndarray,
               an: np.ndarray, mode: np.ndarray, h: np.ndarray) -> None:
    """``PreisachHysteresis.field`` along ``b`` from a committed state (turning points c_in/c_out, state0 =
    (B, H, direction)), each sample committed in turn (:func:`iron_at`); H as ``mode`` = (irreversible,
    saturation) asks into ``h``, the full model's end state into end = (B, H, direction, turns) and
    tin/tout[:turns]."""
    nst, u_prev, y_prev, d, s, br = start_state(c_in, c_out, state0, tin, tout, tabs, psi, virg)
    irreversible, saturation = mode[0] != 0, mode[1] != 0
    for k in range(b.size):
        y, hk, ds, nst, s, br = iron_at(b[k], u_prev, y_prev, d, nst, tin, tout, s, br, tabs, psi, virg, an,
                                         irreversible, saturation)
        h[k] = hk
        u_prev, y_prev, d = b[k], y, ds
    end[0], end[1], end[2], end[3] = u_prev, y_prev, d, nst


def field_along(iron: "PreisachHysteresis", b_t: np.ndarray, state: HysteresisState, *, irreversible: bool = True,
                saturation: bool = True) -> tuple[np.ndarray, HysteresisState]:
    """``iron.field(b_t, state, ...)``: by :func:`iron_field` when numba runs (same numbers, tested
    equal), else by the numpy reference itself."""
    if not enabled():
        return iron.field(b_t, state, irreversible=irreversible, saturation=saturation)
    b = np.ascontiguousarray(b_t, dtype=np.float64)
    turns = np.array(state.turns, dtype=np.float64).reshape(len(state.turns), 2)
    tin, tout = np.empty(turns.shape[0] + b.size + 2), np.empty(turns.shape[0] + b.size + 2)
    end, h = np.empty(4), np.empty(b.size)
    iron_field(b, np.ascontiguousarray(turns[:, 0]), np.ascontiguousarray(turns[:, 1]),
               np.array([state.b_t, state.h_a_per_m, float(state.direction)]), tin, tout, end, *iron.kernel_tables(),
               np.array([irreversible, saturation], dtype=np.int64), h)
    m = int(end[3])
    return h, HysteresisState(float(end[0]), float(end[1]), int(end[2]), tuple(zip(tin[:m].tolist(), tout[:m].tolist())))
