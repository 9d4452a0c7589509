"""Rate-independent hysteresis of the iron: a classical Preisach model, run with B as the input.

The material is identified as the textbook Preisach model with H as input, B = B_rev(H) + P[H]:
relays switching up at alpha and down at beta are what domain-wall pinning does, and with a
*factorised* density mu(alpha, beta) ∝ f(alpha) f(-beta) (Della Torre, Bertotti) the measured major
loop alone fixes f (its branch slope), so minor loops follow without minor-loop data.  A Preisach
model with thresholds in B, fitted to the same major loop, cannot do this: its inner branches are
never steeper (in H against B) than the major loop's, while in SiFe they are much steeper, so it
would predict nearly lossless minor loops.

The simulator knows B, so :meth:`PreisachHysteresis.field` runs the same model backwards.  Every
branch is monotone, so reversals and wiped-out turning points are the same events in B as in H; the
ascending branch from a reversal (H_r, B_r) depends on H_r and B - B_r only (congruency), and a
descending branch is a mirrored ascending one (odd symmetry).  That inverse branch is tabulated once
on (asinh-warped H_r) x (sqrt-warped B - B_r) and read by vectorised bilinear interpolation; Python
runs once per reversal only (the turning-point stack and the wiping-out rule).  Each branch is closed
onto the turning point it returns to, so return-point memory holds exactly, not to the table's
error (:func:`_closure`).  The demagnetised
state is the virgin staircase: beyond the largest |input| seen, the output follows the virgin curve.
Consistency with the H-driven model (:meth:`flux_density`): within 1 mT of B (tests).
"""

from __future__ import annotations

import threading
from dataclasses import dataclass, field as dc_field
from functools import cached_property
from typing import Any, Callable

import numpy as np
from numpy.typing import ArrayLike
from scipy.constants import mu_0
from scipy.special import erf

from ..config.presets import check_material
from ..errors import ConfigError
from ..jit import enabled as jit_enabled

__all__ = ["PreisachParams", "HysteresisState", "PreisachHysteresis", "mu_0"]


@dataclass(frozen=True)
class PreisachParams:
    """Material parameters (SI).  ``components``: (kind, weight, centre_a_per_m, width_a_per_m) of
    the up-switching field density f; ``reversible``: (j_t, h_a_per_m) terms J 2/pi atan(H/h)."""

    j_irr_t: float
    components: tuple[tuple[str, float, float, float], ...]
    reversible: tuple[tuple[float, float], ...]
    h_max_a_per_m: float = 5.0e4
    h_scale_a_per_m: float = 10.0
    fine_nodes: int = 4001
    table_rows: int = 1001
    table_cols: int = 1024


@dataclass(frozen=True)
class HysteresisState:
    """Where the iron is: last (B, H), direction of motion, remembered turning points (B, H).

    Frozen, so a caller can keep it and replay from it; demagnetised is all zeros and no turns."""

    b_t: float = 0.0
    h_a_per_m: float = 0.0
    direction: int = 0
    turns: tuple[tuple[float, float], ...] = dc_field(default=())


def _lerp(a: np.ndarray, b: np.ndarray, t: np.ndarray) -> np.ndarray:
    """a + t (b - a), in place in ``a`` (``b`` is overwritten)."""
    b -= a
    b *= t
    a += b
    return a


class _Work(threading.local):
    """Scratch arrays reused from call to call: fresh 100 000-sample temporaries cost more in page
    faults than the arithmetic does.  Per thread, so one model may serve several threads."""

    def __init__(self) -> None:
        self.bufs: dict[str, np.ndarray] = {}

    def get(self, name: str, n: int, dtype: type = float) -> np.ndarray:
        a = self.bufs.get(name)
        if a is None or a.size < n:
            a = self.bufs[name] = np.empty(max(n, 1), dtype)
        return a[:n]


@dataclass
class _Plan:
    """What the turning-point bookkeeping decided for one block (indices into the block)."""

    starts: np.ndarray  # first sample of each sub-segment
    refs: np.ndarray  # turning-point id whose branch the sub-segment follows, -1 = virgin curve
    tgts: np.ndarray  # the turning point that branch returns to (-2: the mirror of refs, -1: none)
    dirs: np.ndarray  # +1 ascending, -1 descending
    t_in: list[float]  # input value of every turning point (old stack first, then new ones)
    t_ref: list[int]  # reference of each new turning point (-1 virgin)
    t_tgt: list[int]  # the turning point its reference's branch returns to (as tgts)
    t_dir: list[int]
    t_depth: list[int]
    n_old: int
    stack: list[int]
    direction: int


def _plan(u: np.ndarray, u0: float, d0: int, stack_in: list[float], work: _Work) -> _Plan:
    """Find reversals with numpy; run the wiping-out rule once per reversal in Python."""
    n = u.size
    sg = work.get("sign", n)
    sg[0] = u[0] - u0
    np.subtract(u[1:], u[:-1], out=sg[1:])
    np.sign(sg, out=sg)
    zeros = np.flatnonzero(sg == 0.0)
    if zeros.size > 64:  # plateaus keep the previous direction
        pos = np.where(sg != 0, np.arange(n), -1)
        np.maximum.accumulate(pos, out=pos)
        sg[:] = np.where(pos >= 0, sg[pos], float(d0))
    else:
        for k in zeros.tolist():
            sg[k] = sg[k - 1] if k else d0
    changed = work.get("changed", n - 1, bool)
    np.not_equal(sg[1:], sg[:-1], out=changed)
    rev = np.flatnonzero(changed) + 1
    if rev.size and sg[rev[0] - 1] == 0:  # first motion after a standstill: not a reversal
        rev = rev[1:]
    head = [0, 0] if d0 != 0 and sg[0] != d0 else [0]  # reversal right at the block boundary
    bounds = np.concatenate((head, rev, [n])).astype(np.intp)
    last = bounds[1:] - 1
    bl, en, sd = bounds.tolist(), u[last].tolist(), sg[last].tolist()
    nseg = len(bl) - 1
    # turning point ids: the old stack first, then one per reversal (the end of segment m)
    n_old = len(stack_in)
    t_in = list(stack_in) + en[: nseg - 1]
    t_dir = sd[: nseg - 1]
    if len(head) == 2:
        t_in[n_old], t_dir[0] = u0, d0
    depth = [0] * len(t_in)
    t_ref: list[int] = []
    t_tgt: list[int] = []
    stack = list(range(n_old))
    starts: list[int] = []
    refs: list[int] = []
    tgts: list[int] = []

    def target() -> int:
        return stack[-2] if len(stack) > 1 else (-2 if stack else -1)
    for m in range(nseg):
        a, b = bl[m], bl[m + 1]
        if b > a:
            starts.append(a)
            refs.append(stack[-1] if stack else -1)
            tgts.append(target())
            s, end = sd[m], en[m]
            while stack:
                thr = t_in[stack[-2]] if len(stack) > 1 else -t_in[stack[0]]
                if (end < thr) if s > 0 else (end > thr):
                    break
                del stack[-2:]  # wiping out: the inner pair is forgotten from the sample reaching thr
                pen = u[b - 2] if b - a >= 2 else thr
                if (pen < thr) if s > 0 else (pen > thr):
                    k = b - 1
                elif s > 0:
                    k = a + int(u[a:b].searchsorted(thr, "left"))
                else:
                    k = b - int(u[a:b][::-1].searchsorted(thr, "right"))
                r = stack[-1] if stack else -1
                if k == starts[-1]:
                    refs[-1], tgts[-1] = r, target()
                else:
                    starts.append(k)
                    refs.append(r)
                    tgts.append(target())
        if m < nseg - 1:  # a reversal: the segment's last sample (or u0) is a turning point
            ref = stack[-1] if stack else -1
            t_ref.append(ref)
            t_tgt.append(target())
            if ref >= n_old:
                depth[n_old + m] = depth[ref] + 1
            stack.append(n_old + m)
    st = np.asarray(starts, np.intp)
    return _Plan(st, np.asarray(refs, np.intp), np.asarray(tgts, np.intp), sg[st].copy(), t_in, t_ref, t_tgt,
                 t_dir, depth[n_old:], n_old, stack, int(sg[-1]) if n else d0)


#: A branch's miss is closed over at least this much of its input (T, or A/m when H is the input);
#: a shorter reach (a miss below ~1e-6 A/m) is left as the step it is, rather than divided by.
MIN_REACH = 1e-12


def _closure(branch: Callable, virgin: Callable, t_in: np.ndarray, t_out: np.ndarray, ref: np.ndarray,
             tgt: np.ndarray, s: np.ndarray, min_slope: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Return-point memory, made exact: the branch from turning point ``ref`` must reach the turning
    point ``tgt`` it returns to (-2: the mirror of ``ref`` on the virgin curve; -1: none), where
    the loop is wiped out.  A tabulated branch misses it by its table error (1e-3 A/m at 0.3 T,
    1-5 A/m near the knee, ~100 A/m deep in saturation), so H would step there, and whether a later
    extremum that ties with an earlier one (a periodic B) falls just short of it or just past would
    decide the iron's state for ever.  Returns (the miss, the target, the reach), per branch:
    :func:`_closed` adds the miss over the last ``reach`` of the way, which is as short as keeps the
    branch rising at half its own slope there at least (``min_slope``: the flattest branch's), so
    the correction stays where the table erred and never bends a branch back."""
    ref_in, ref_out = t_in[ref], t_out[ref]
    mirror, none = tgt == -2, tgt == -1
    tgt_in = np.where(mirror, -ref_in, t_in[np.maximum(tgt, -1)])
    tgt_out = t_out[np.maximum(tgt, -1)]
    if mirror.any():
        tgt_out = np.where(mirror, 0.0, tgt_out)
        tgt_out[mirror] = virgin(tgt_in[mirror])
    at_t = branch(ref_in, ref_out, s, tgt_in)
    miss = tgt_out - at_t
    miss[none | (ref < 0)] = 0.0
    twice = 2.0 * np.abs(miss)
    wide = np.minimum(s * (tgt_in - ref_in), twice / min_slope)
    chord = s * (at_t - branch(ref_in, ref_out, s, tgt_in - s * wide))  # the branch's rise over ``wide``
    reach = np.minimum(wide, np.divide(twice * wide, chord, out=wide.copy(), where=chord > 0.0))
    return miss, tgt_in, reach


def _closed(y: np.ndarray, u: np.ndarray, seg: np.ndarray, s: np.ndarray, miss: np.ndarray, tgt_in: np.ndarray,
            reach: np.ndarray, work: _Work) -> np.ndarray:
    """``y`` with each branch's miss added over the last ``reach`` of its way (:func:`_closure`);
    sample k follows branch ``seg[k]``."""
    on = reach > MIN_REACH
    miss, reach = np.where(on, miss, 0.0), np.where(on, reach, 1.0)
    way = np.take(tgt_in, seg, out=work.get("way", u.size))
    way -= u
    way *= np.take(s / reach, seg, out=work.get("scale", u.size))
    np.subtract(1.0, way, out=way)
    np.clip(way, 0.0, 1.0, out=way)
    way *= np.take(miss, seg, out=work.get("scale", u.size))
    y += way
    return y


def _run(u, state: HysteresisState, coord: int, branch: Callable, virgin: Callable, work: _Work,
         min_slope: float | None = None):
    """Shared driver: ``coord`` 0 = B is the input, 1 = H is the input.  ``branch(ref_in,
    ref_out, direction, u, starts)`` evaluates branches (per sub-segment when ``starts`` is given);
    ``min_slope``: the branches are read from tables, none flatter than that (output per input),
    and each is made to reach the turning point it returns to (:func:`_closure`); None for
    branches that meet their turning points by construction."""
    u = np.ascontiguousarray(u, dtype=float)
    if u.ndim != 1:
        raise ValueError(f"input must be 1-D, got shape {u.shape}")
    u0 = (state.b_t, state.h_a_per_m)[coord]
    if u.size == 0:
        return u.copy(), state
    p = _plan(u, u0, state.direction, [t[coord] for t in state.turns], work)
    t_in = np.append(p.t_in, 0.0)  # the extra last entry stands in for "virgin" (ref -1)
    t_out = np.zeros(t_in.size)
    t_out[: p.n_old] = [t[1 - coord] for t in state.turns]
    if p.t_ref:
        new = np.arange(p.n_old, len(p.t_in))
        ref, tgt = np.asarray(p.t_ref, np.intp), np.asarray(p.t_tgt, np.intp)
        sdir, dep = np.asarray(p.t_dir, float), np.asarray(p.t_depth)
        for level in range(int(dep.max()) + 1):  # a turning point needs its reference's output
            sel = dep == level
            ids, r, s = new[sel], ref[sel], sdir[sel]
            out = branch(t_in[r], t_out[r], s, t_in[ids])
            if min_slope is not None:
                out = _closed(out, t_in[ids], np.arange(ids.size), s,
                              *_closure(branch, virgin, t_in, t_out, r, tgt[sel], s, min_slope), work)
            vg = r < 0
            if vg.any():
                out[vg] = virgin(t_in[ids[vg]])
            t_out[ids] = out
    y = branch(t_in[p.refs], t_out[p.refs], p.dirs, u, p.starts)
    if min_slope is not None:
        miss, tgt_in, reach = _closure(branch, virgin, t_in, t_out, p.refs, p.tgts, p.dirs, min_slope)
        if np.any(miss):
            seg = np.repeat(np.arange(p.starts.size), np.diff(np.append(p.starts, u.size)))
            y = _closed(y, u, seg, p.dirs, miss, tgt_in, reach, work)
    vseg = np.flatnonzero(p.refs < 0)
    if vseg.size:  # samples on the virgin curve, gathered in one go
        lv = np.diff(np.append(p.starts, u.size))[vseg]
        idx = np.repeat(p.starts[vseg] - np.cumsum(lv) + lv, lv) + np.arange(lv.sum())
        y[idx] = virgin(u[idx])
    turns = tuple((float(t_in[i]), float(t_out[i]))[:: 1 - 2 * coord] for i in p.stack)
    last = (float(u[-1]), float(y[-1]))[:: 1 - 2 * coord]
    return y, HysteresisState(last[0], last[1], p.direction, turns)


#: PreisachHysteresis._inverse per material (PreisachParams is frozen, so it is the key)
_INVERSE_TABLES: dict[PreisachParams, dict[str, Any]] = {}


class PreisachHysteresis:
    """The iron's B-H relation with static hysteresis; see the module docstring for why."""

    def __init__(self, params: PreisachParams):
        self.params = p = params
        self._work = _Work()
        hmax, h0 = p.h_max_a_per_m, p.h_scale_a_per_m
        self._h0 = h0
        self._xmax = float(np.arcsinh(hmax / h0))
        x = np.linspace(-self._xmax, self._xmax, p.fine_nodes)
        h = h0 * np.sinh(x)
        h[0], h[-1], h[p.fine_nodes // 2] = -hmax, hmax, 0.0
        self._x, self._h = x, h
        self._dx = x[1] - x[0]
        cdf_f, pdf_f = self._cdf_pdf(h)  # F(H): share of up-switching fields below H
        self._F = cdf_f - cdf_f[0]
        self._G = cdf_f[-1] - self._cdf_pdf(-h)[0]  # share of down-switching fields in [-h_max, H]
        # K(H) = ∫ f G dH, trapezoid in x with the Euler-Maclaurin end correction (4th order)
        phi = pdf_f * self._G * h0 * np.cosh(x)
        dx = x[1] - x[0]
        trap = np.concatenate(([0.0], np.cumsum(0.5 * dx * (phi[1:] + phi[:-1]))))
        dphi = np.gradient(phi, dx)
        self._K = trap - dx * dx / 12.0 * (dphi - dphi[0])
        z = self._K[-1]  # E(Hmax, -Hmax) before scaling
        if not z > 0.0:
            raise ConfigError("Preisach distribution has no weight inside +-h_max")
        scale = p.j_irr_t / z
        self._F *= np.sqrt(scale)
        self._G *= np.sqrt(scale)
        self._K *= scale
        self._brev = self._b_rev_exact(h)
        self._s_end = mu_0 + sum(j * 2 / np.pi * hr / (hr * hr + hmax * hmax) for j, hr in p.reversible)

    # ---- construction from a material file -------------------------------------------------
    @classmethod
    def from_config(cls, material: dict[str, Any]) -> "PreisachHysteresis":
        """From ``hystbench.config.load_material(name)`` (a dict built otherwise is checked here
        against the same schema); a bad key raises ConfigError naming the file and the key."""
        m = check_material(material)
        if m["model"] != "preisach-factorised":  # the other models: hystbench.physics.iron.iron_model
            raise ConfigError(f"{m['_source']}: model {m['model']!r} is not a Preisach model")
        pre = m["preisach"]
        comps = tuple((c["kind"], c["weight"], c["centre_a_per_m"], c["width_a_per_m"]) for c in pre["components"])
        terms = tuple((t["j_t"], t["h_a_per_m"]) for t in m["reversible"]["terms"])
        return cls(PreisachParams(components=comps, reversible=terms, j_irr_t=pre["j_irr_t"],
                                  h_max_a_per_m=pre["h_max_a_per_m"], h_scale_a_per_m=pre["h_scale_a_per_m"]))

    def initial_state(self) -> HysteresisState:
        """Demagnetised (after a slowly decaying AC field): B = 0, H = 0, nothing remembered."""
        return HysteresisState()

    # ---- the single-valued pieces ----------------------------------------------------------
    def _cdf_pdf(self, h):
        """Distribution and density of the up-switching field (weights normalised to 1)."""
        cdf, pdf = np.zeros_like(h), np.zeros_like(h)
        total = sum(c[1] for c in self.params.components)
        for kind, w, c, s in self.params.components:
            zz = (h - c) / s
            if kind == "gauss":
                cdf += w / total * 0.5 * (1 + erf(zz / np.sqrt(2)))
                pdf += w / total * np.exp(-0.5 * zz * zz) / (np.sqrt(2 * np.pi) * s)
            else:
                cdf += w / total * (0.5 + np.arctan(zz) / np.pi)
                pdf += w / total / (np.pi * s * (1 + zz * zz))
        return cdf, pdf

    def _b_rev_exact(self, h):
        out = mu_0 * h
        for j, hr in self.params.reversible:
            out = out + j * 2 / np.pi * np.arctan(h / hr)
        return out

    def b_rev(self, h: ArrayLike) -> np.ndarray:
        """Reversible part B_rev(H); straight beyond +-h_max (the relays are all switched there)."""
        h = np.asarray(h, float)
        hm = self.params.h_max_a_per_m
        hc = np.clip(h, -hm, hm)
        return self._b_rev_exact(hc) + self._s_end * (h - hc)

    def _lookup(self, h):
        """Fine-grid index and fraction of H (clipped to +-h_max)."""
        xi = (np.arcsinh(np.clip(h, -self.params.h_max_a_per_m, self.params.h_max_a_per_m) / self._h0)
              + self._xmax) / self._dx
        i = np.minimum(xi.astype(np.intp), self._x.size - 2)
        return i, xi - i

    def everett(self, alpha: ArrayLike, beta: ArrayLike) -> np.ndarray:
        """E(alpha, beta) (T), weight of relays with beta <= down, up <= alpha; alpha >= beta.

        Factorised density: E = K(a) - K(b) - G(b) (F(a) - F(b)), from three 1-D tables."""
        ia, ta = self._lookup(np.asarray(alpha, float))
        ib, tb = self._lookup(np.asarray(beta, float))

        def at(t, i, w):
            return t[i] + w * (t[i + 1] - t[i])

        f_a, f_b = at(self._F, ia, ta), at(self._F, ib, tb)
        e = at(self._K, ia, ta) - at(self._K, ib, tb) - at(self._G, ib, tb) * (f_a - f_b)
        return np.maximum(e, 0.0)

    # ---- H as the input (identification, tests) -------------------------------------------
    def flux_density(self, h_t: ArrayLike, state: HysteresisState) -> tuple[np.ndarray, HysteresisState]:
        """B (T) along the field trajectory h_t (A/m): the model as identified."""

        def branch(h_r, b_r, s, h, starts=None):
            if starts is not None:
                lens = np.diff(np.append(starts, h.size))
                h_r, b_r, s = np.repeat(h_r, lens), np.repeat(b_r, lens), np.repeat(s, lens)
            hi, lo = np.maximum(h, h_r), np.minimum(h, h_r)
            return b_r + 2 * s * self.everett(hi, lo) + self.b_rev(h) - self.b_rev(h_r)

        def virgin(h):
            a = np.abs(h)
            return self.b_rev(h) + np.sign(h) * self.everett(a, -a)

        return _run(h_t, state, 1, branch, virgin, self._work)

    # ---- B as the input (the simulator) ----------------------------------------------------
    @cached_property
    def _inverse(self) -> dict[str, Any]:
        """The B-driven tables, shared by every instance of one material: building them costs
        about 50 ms, and a diagnosis builds a rig per simulation (read-only arrays)."""
        tables = _INVERSE_TABLES.get(self.params)
        if tables is None:
            tables = self._build_inverse()
            for value in tables.values():
                for array in value if isinstance(value, tuple) else (value,):
                    if isinstance(array, np.ndarray):
                        array.flags.writeable = False
            if len(_INVERSE_TABLES) >= 16:
                _INVERSE_TABLES.clear()
            _INVERSE_TABLES[self.params] = tables
        return tables

    def _build_inverse(self) -> dict[str, Any]:
        """Inverse branch table psi[row, col] = H on the ascending branch from H_r.

        Rows: H_r on every ``step``-th fine node; columns: B - B_r = dmax (k/K)^2 (fine near the
        reversal, where small loops live)."""
        p = self.params
        step = (p.fine_nodes - 1) // (p.table_rows - 1)
        rows = np.arange(0, p.fine_nodes, step)
        k = p.table_cols
        dmax = float(2 * p.j_irr_t + self._brev[-1] - self._brev[0])
        db = dmax * (np.arange(k + 1) / k) ** 2
        psi = np.empty((rows.size, k + 2))  # one spare column: the lookup never needs a clip
        x, h = self._x, self._h
        if jit_enabled():
            from .hysteresis_kernel import ascending_branches

            ascending_branches(rows, db, x, self._K, self._G, self._F, self._brev, float(h[-1]), float(self._h0),
                               float(self._s_end), psi)
        else:
            for r, j in enumerate(rows):
                e = self._K[j:] - self._K[j] - self._G[j] * (self._F[j:] - self._F[j])
                g = 2 * e + self._brev[j:] - self._brev[j]
                g = np.maximum.accumulate(g)
                xs = np.interp(db, g, x[j:])
                psi[r, :-1] = np.where(db <= g[-1], self._h0 * np.sinh(xs), h[-1] + (db - g[-1]) / self._s_end)
        psi[:, -1] = psi[:, -2]
        # virgin curve and anhysteretic curve, inverted on a uniform B grid (odd functions)
        iv = slice(p.fine_nodes // 2, None)
        hv = h[iv]
        K, G, F = self._K, self._G, self._F  # virgin: B_rev(H) + E(H, -H), mirror nodes
        bv = self._brev[iv] + K[iv] - K[::-1][iv] - G[::-1][iv] * (F[iv] - F[::-1][iv])
        ban = self._brev[iv] + self._anhysteretic_irr(hv)
        nb = 4096
        return dict(
            psi=psi.ravel(), ncol=k + 2, nrow=rows.size, x0=x[0], dx_rows=x[rows[1]] - x[rows[0]],
            dmax=dmax, kcol=k / np.sqrt(dmax),
            min_slope=float(np.min(np.diff(psi[:, : k + 1], axis=1) / np.diff(db))),
            virgin=self._uniform_inverse(np.maximum.accumulate(bv), hv, nb),
            anhyst=self._uniform_inverse(np.maximum.accumulate(ban), hv, nb),
        )

    def _uniform_inverse(self, b, h, nb):
        grid = np.linspace(0.0, b[-1], nb + 1)
        return grid[1] - grid[0], np.interp(grid, b, h)

    def _read_uniform(self, table, b):
        """Odd 1-D table H(|B|) with the straight continuation beyond its end."""
        step, t = table
        a = np.abs(b) / step
        ac = np.minimum(a, t.size - 1)
        i = np.minimum(ac.astype(np.intp), t.size - 2)
        return np.sign(b) * (t[i] + (ac - i) * (t[i + 1] - t[i]) + (a - ac) * step / self._s_end)

    def _anhysteretic_irr(self, h):
        """Preisach part of the anhysteretic curve: relays centred below H are up, the rest down.

        Weight centred below hv: integral of f(alpha) G(min(alpha, 2 hv - alpha)); evaluated on
        every 8th point and interpolated (it is smooth on the warped grid)."""
        hh, G = self._h, self._G
        f = np.gradient(self._F, hh)
        coarse = np.append(h[::8], h[-1])
        gi = np.interp(np.minimum(hh[None, :], 2 * coarse[:, None] - hh[None, :]), hh, G, left=0.0)
        out = 2 * np.trapezoid(f * gi, hh, axis=1) - self.params.j_irr_t
        return np.interp(h, coarse, out)

    def field(self, b_t: ArrayLike, state: HysteresisState, *, irreversible: bool = True, saturation: bool = True
              ) -> tuple[np.ndarray, HysteresisState]:
        """H (A/m) along the flux-density trajectory b_t (T), continuing from ``state``.

        ``irreversible=False`` gives the anhysteretic curve H_an(B) (``static_hysteresis`` off);
        ``saturation=False`` replaces H_an(B) by its tangent at B = 0 and keeps the hysteretic
        part H - H_an(B), which vanishes in saturation (``iron_saturation`` off).  The returned
        state is that of the full model either way.  Every branch meets the turning point it
        returns to (:func:`_closure`), so loops nested between extrema that tie (a periodic B)
        neither drift apart level by level nor step H where a later extremum wipes them out."""
        inv = self._inverse
        psi, ncol, nrow, dmax, kcol = inv["psi"], inv["ncol"], inv["nrow"], inv["dmax"], inv["kcol"]
        x0, inv_dx = inv["x0"], 1.0 / inv["dx_rows"]
        h0, s_end, hmax = self._h0, self._s_end, self.params.h_max_a_per_m

        def branch(b_r, h_r, s, b, starts=None):
            hs = s * h_r  # the ascending frame: a descending branch is a mirrored ascending one
            c1 = s * b_r
            low, high = hs < -hmax, hs > hmax  # reversal beyond +-h_max: the straight part first
            edge = bool(low.any() or high.any())
            if edge:
                c1 = c1 + np.where(low, s_end * (-hmax - hs), 0.0)
                shift = np.maximum(hs - hmax, 0.0)
                hs = np.clip(hs, -hmax, hmax)
            fr = (np.arcsinh(hs / h0) - x0) * inv_dx
            jr = np.minimum(fr.astype(np.intp), nrow - 2)
            tr = fr - jr
            base = jr * ncol
            n = b.size
            get = self._work.get
            if starts is not None:  # per sub-segment values, spread over their samples
                seg = get("seg", n, np.intp)
                seg.fill(0)
                seg[starts[1:]] = 1
                np.cumsum(seg, out=seg)
                s, c1, base, tr = (np.take(v, seg, out=get(k, n, v.dtype))
                                   for k, v in (("s", s), ("c1", c1), ("base", base), ("tr", tr)))
                if edge:
                    shift = shift[seg]
            d = np.multiply(s, b, out=get("d", n))
            d -= c1
            neg = np.minimum(d, 0.0) if edge else None
            np.maximum(d, 0.0, out=d)
            over = float(d.max()) > dmax
            extra = np.maximum(d - dmax, 0.0) / s_end if over else None
            np.sqrt(d, out=d)
            d *= kcol
            ik = get("ik", n, np.intp)
            np.copyto(ik, d, casting="unsafe")  # floor: d >= 0
            if over:
                np.minimum(ik, ncol - 2, out=ik)
                np.minimum(d, ncol - 2, out=d)
            d -= ik  # fraction along the column axis
            ik += base
            v0 = psi.take(ik, out=get("v0", n))
            ik += 1
            v1 = psi.take(ik, out=get("v1", n))
            ik += ncol
            w1 = psi.take(ik, out=get("w1", n))
            ik -= 1
            w0 = psi.take(ik, out=get("w0", n))
            w0 = _lerp(w0, w1, d)
            v0 = _lerp(_lerp(v0, v1, d), w0, tr)
            if edge:
                v0 += neg / s_end + shift
            if over:
                v0 += extra
            return np.multiply(v0, s, out=np.empty(n)) if starts is not None else v0 * s

        def virgin(b):
            return self._read_uniform(inv["virgin"], b)

        h, new_state = _run(b_t, state, 0, branch, virgin, self._work, inv["min_slope"])
        if irreversible and saturation:
            return h, new_state
        b = np.asarray(b_t, float)
        h_an = self._read_uniform(inv["anhyst"], b)
        single = h_an if saturation else self.small_signal_dh_db * b
        return (single + (h - h_an) if irreversible else single), new_state

    def kernel_tables(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """What a compiled kernel needs to evaluate :meth:`field` sample by sample, so it reads no
        private attribute: (scalars, psi, virgin, anhysteretic), float64 and contiguous.  scalars =
        (h0, x0, 1/dx_rows, nrow, ncol, h_max, s_end, dmax, kcol, virgin step, anhysteretic step,
        small_signal_dh_db, the flattest branch's dH/dB, MIN_REACH), in that order
        (hystbench.sim_backend.actuators.ecore_kernel)."""
        inv = self._inverse
        (v_step, virgin), (a_step, anhyst) = inv["virgin"], inv["anhyst"]
        scalars = np.array([self._h0, inv["x0"], 1.0 / inv["dx_rows"], inv["nrow"], inv["ncol"],
                            self.params.h_max_a_per_m, self._s_end, inv["dmax"], inv["kcol"], v_step, a_step,
                            self.small_signal_dh_db, inv["min_slope"], MIN_REACH], dtype=np.float64)
        return (scalars, np.ascontiguousarray(inv["psi"], dtype=np.float64),
                np.ascontiguousarray(virgin, dtype=np.float64), np.ascontiguousarray(anhyst, dtype=np.float64))

    @cached_property
    def small_signal_dh_db(self) -> float:
        """dH/dB of the anhysteretic curve at B = 0 (A/m per T), slope of the unsaturated iron."""
        step, t = self._inverse["anhyst"]
        return float((t[1] - t[0]) / step)

    @cached_property
    def max_flux_density_t(self) -> float:
        """B at the end of the model's field range, H = h_max, every relay switched (T).  Beyond it
        the model goes on straight with the slope it has there, which no material does (the
        reversible part bends on towards mu0): a simulation past it would invent the iron."""
        return float(self.b_rev(self.params.h_max_a_per_m)) + self.params.j_irr_t

    def anhysteretic_field(self, b: ArrayLike) -> np.ndarray:
        """H_an(B) (A/m): the single-valued curve with static hysteresis switched off."""
        return self._read_uniform(self._inverse["anhyst"], np.asarray(b, float))
