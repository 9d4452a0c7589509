"""The E-core actuator's block step as numba kernels: the same arithmetic as the numpy code in
:mod:`.ecore` (the reference, and the fallback without numba), sample by sample in one loop per pass.

Why: the numpy step makes 5-20 passes over the block with a temporary each (the Preisach branch
reads alone about 20), three times per block (two fixed-point passes and the final run), plus a
Python loop per reversal; one compiled loop per pass holds everything in registers (issue 14).

What stays equal: the fixed-point iteration (first guess from the last period, WARM_PASSES or
IRON_ITERATIONS passes, convergence checked from then on, MAX_PASSES at most), every pass starting
from the block's committed states, the turning-point rule of :func:`hystbench.physics.hysteresis._plan`
(plateaus keep their direction; a reversal pushes the previous sample; reaching the threshold pops
the inner pair, -t[0] for a single turn, which returns to the virgin curve), the branch arithmetic of
``PreisachHysteresis.field`` in its operation order, and the final run's formulas.  numpy's 2x2
matmuls may fuse multiply-adds where this code rounds twice: that, and libm's asinh, is the only
difference (about 1e-12 of a channel's range).  No fastmath: it would reorder operations.

The Preisach iron's helpers (branch constants and reads, one sample's turning-point rule) live in
:mod:`hystbench.physics.hysteresis_kernel`, shared with the fits that run the iron alone.  numba's
on-disk cache is invalidated by a change of the file that defines the cached function only, not of
the files whose jitted helpers it inlines, so this module drops its cache when that file changes
(:func:`hystbench.jit.drop_stale_cache`): an edit never runs against a stale compiled copy.
"""

from __future__ import annotations

import math

import numpy as np

from ...jit import drop_stale_cache, njit
from ...physics import hysteresis_kernel
from ...physics.hysteresis_kernel import branch_at, branch_consts, iron_at, read_uniform, start_state

# the passes inline the Preisach helpers of hysteresis_kernel: numba's cache of this file must go when
# that file changes (it is keyed on this file alone)
drop_stale_cache(__file__, hysteresis_kernel.__file__)

__all__ = ["first_guess", "passes", "final_run"]

#: what :func:`passes` reports: a pass converged / none did within max_passes
SETTLED, UNSETTLED = 1, 0


@njit(cache=True, nogil=True)
def first_guess(hist: np.ndarray, period: float, out: np.ndarray) -> None:
    """The iron's remainder one (fractional) period earlier: ``np.interp(size - p + k % p, ...)``,
    with k % p kept incrementally (exact: fmod's result plus 1 is representable) and recomputed at
    each wrap; clamped at the last sample as np.interp is."""
    size = hist.size
    ph = 0.0
    for k in range(out.size):
        pos = size - period + ph
        ph += 1.0
        if ph >= period:
            ph = float(k + 1) % period
        j = int(pos)
        if j >= size - 1:
            out[k] = hist[size - 1]
        else:
            out[k] = (hist[j + 1] - hist[j]) * (pos - j) + hist[j]


@njit(cache=True, nogil=True)
def _one_pass(fc, fm, h_rest, lag, y_start, cold, c_in, c_out, state0, tin, tout, end, tabs, psi, virg, an,
              mode, knee, nu0, gain, length, track, rate, scale):
    """One fixed-point pass (ECoreActuator._pass) from the committed states, h_rest updated in place.
    ``rate``: the iron's rate terms (:func:`rate_terms`; hystbench.physics.rate_dependence) added to H,
    their slope damping the step as in ECoreActuator._damped; ``scale``: the static field's factor at each
    sample (the iron's temperature, hystbench.physics.iron_thermal; empty: none).
    Returns (max |step|, max |h_rest|, max |B|) (tracked only when ``track``); the iron's state at
    the block's end goes to end = (B, H, direction, number of turns) and tin/tout[:turns]."""
    n = fc.size
    lam0, lam1, q00, q01, q10, q11, v00, v01 = lag[0], lag[1], lag[2], lag[3], lag[4], lag[5], lag[6], lag[7]
    s_end, v_step, a_step, ss = tabs[6], tabs[9], tabs[10], tabs[11]
    irreversible, saturation = mode[0] != 0, mode[1] != 0
    full = irreversible and saturation
    if cold:  # lfilter's y[-1] = w[0] / (1 - lam), from this pass's first input
        u0 = fc[0] - h_rest[0] * length
        ya = (q00 * u0 + q01 * fm[0]) / (1.0 - lam0)
        yb = (q10 * u0 + q11 * fm[0]) / (1.0 - lam1)
    else:
        ya, yb = y_start[0], y_start[1]
    nst, u_prev, y_prev, d, s, br = start_state(c_in, c_out, state0, tin, tout, tabs, psi, virg)
    virgin = nst == 0
    mstep, mh, mb = 0.0, 0.0, 0.0
    has_ex, k_ex, r0, has_rel, a_rel, kappa, fs = rate[0] != 0.0, rate[1], rate[2], rate[3] != 0.0, rate[4], rate[5], rate[6]
    bp, bs, sqr0 = rate[7], rate[8], math.sqrt(rate[2])
    scaled = scale.size > 0
    for k in range(n):
        hr = h_rest[k]
        u0 = fc[k] - hr * length
        u1 = fm[k]
        ya = lam0 * ya + (q00 * u0 + q01 * u1)
        yb = lam1 * yb + (q10 * u0 + q11 * u1)
        b = v00 * ya + v01 * yb
        # the turning-point bookkeeping of hysteresis._plan, one sample at a time: iron_at's rule written
        # out (calling iron_at here, its branch tuple returned per sample, made the rig 1.55x slower)
        diff = b - u_prev
        ds = 1.0 if diff > 0.0 else (-1.0 if diff < 0.0 else d)
        reset = False
        if ds != d:
            if d != 0.0:  # a reversal at the previous sample: it becomes a turning point
                tin[nst] = u_prev
                tout[nst] = y_prev
                nst += 1
            reset = True
        while nst > 0:  # wiping out: reaching the threshold forgets the inner pair
            thr = tin[nst - 2] if nst > 1 else -tin[0]
            if (b < thr) if ds > 0.0 else (b > thr):
                break
            nst = max(nst - 2, 0)
            reset = True
        if reset:
            s = ds
            virgin = nst == 0
            if not virgin:
                br = branch_consts(s, nst, tin, tout, tabs, psi, virg)
        if virgin:
            y = read_uniform(v_step, virg, s_end, b)
        else:
            y = branch_at(s, br, b, psi, tabs)
        u_prev, y_prev, d = b, y, ds
        h = y
        if not full:  # field(irreversible=..., saturation=...): the state stays the full model's
            h_an = read_uniform(a_step, an, s_end, b)
            single = h_an if saturation else ss * b
            h = single + (y - h_an) if irreversible else single
        if scaled:
            h *= scale[k]
        extra = 0.0  # the remainder's own slope beyond nu0: what damps the step (ECoreActuator._damped)
        if bp != bp:  # NaN: the rig's first block starts at rest, at its first sample's B (RateDependence._start)
            bp, bs = b, b
        if has_ex:  # Bertotti's excess field of the backward difference
            rt = (b - bp) * fs
            sq = math.sqrt(abs(rt) + r0)
            h += k_ex * (1.0 if rt > 0.0 else (-1.0 if rt < 0.0 else 0.0)) * (sq - sqr0)
            extra += 0.5 * k_ex * fs / sq
        if has_rel:  # the relaxation's B_slow, as lfilter([1 - a], [1, -a]) runs it
            bs = (1.0 - a_rel) * b + a_rel * bs
            h += kappa * (b - bs)
            extra += kappa * a_rel
        bp = b
        r = h - nu0 * b - hr
        if abs(b) > knee:  # ECoreActuator._newton_step
            nu_d = max(nu0, (read_uniform(a_step, an, s_end, b + 1e-3)
                             - read_uniform(a_step, an, s_end, b - 1e-3)) / 2e-3)
            extra += nu_d - nu0
        if extra != 0.0:
            r = r / (1.0 + extra * gain * length)
        hr = hr + r
        h_rest[k] = hr
        if track:
            mstep = max(mstep, abs(r))
            mh = max(mh, abs(hr))
            mb = max(mb, abs(b))
    end[0], end[1], end[2], end[3] = u_prev, y_prev, d, nst
    return mstep, mh, mb


@njit(cache=True, nogil=True)
def passes(fc: np.ndarray, fm: np.ndarray, h_rest: np.ndarray, first: int, max_passes: int, converged_ratio: float,
           lag: np.ndarray, y_start: np.ndarray, cold: bool, c_in: np.ndarray, c_out: np.ndarray, state0: np.ndarray,
           tin: np.ndarray, tout: np.ndarray, end: np.ndarray, tabs: np.ndarray, psi: np.ndarray, virg: np.ndarray,
           an: np.ndarray, mode: int, knee: float, nu0: float, gain: float, length: float, out: np.ndarray,
           rate: np.ndarray, scale: np.ndarray) -> None:
    """ECoreActuator.step's loop of passes: at least ``first``, then until one converges, at most
    ``max_passes``.  out = (converged 1/0, passes run, max |B| of the last pass)."""
    done = SETTLED
    peak = 0.0
    n_pass = 0
    for n_pass in range(1, max_passes + 1):
        track = n_pass >= first or n_pass == max_passes  # the last one names |B| in a refusal
        mstep, mh, peak = _one_pass(fc, fm, h_rest, lag, y_start, cold, c_in, c_out, state0, tin, tout, end, tabs,
                                    psi, virg, an, mode, knee, nu0, gain, length, track, rate, scale)
        if track and mstep <= converged_ratio * (mh + 1.0):
            break
    else:
        done = UNSETTLED
    out[0], out[1], out[2] = done, n_pass, peak


@njit(cache=True, nogil=True)
def final_run(fc: np.ndarray, fm: np.ndarray, h_rest: np.ndarray, length: float, lag: np.ndarray, y_start: np.ndarray,
              cold: bool, nd: np.ndarray, fs_hz: float, dlam: np.ndarray, d2lam: np.ndarray, outer: np.ndarray,
              douter: np.ndarray, compliance: float, turns: float, dcur: np.ndarray, dfm: float, prev_drop: np.ndarray,
              force: np.ndarray, flux: np.ndarray, dflux: np.ndarray, iron_b: np.ndarray, lag_end: np.ndarray) -> None:
    """The linear run with the converged remainder, straight into force, flux and its rate
    (ECoreActuator.step after the passes).  nd = (N00, D00, D11): N = diag(nu0 L, 0) and D is
    diagonal (ECoreActuator._linear_part), so the zero terms of numpy's N x + D dx/dt, which add
    exact zeros, are left out; prev_drop: the last block's last two MMF drops (r0, r1 of the last
    sample, then of the one before), NaN where there was none, updated in place; lag_end = (y, x) at
    the block's end."""
    n = fc.size
    lam0, lam1, q00, q01, q10, q11 = lag[0], lag[1], lag[2], lag[3], lag[4], lag[5]
    v00, v01, v10, v11 = lag[6], lag[7], lag[8], lag[9]
    n00, d00, d11 = nd[0], nd[1], nd[2]
    dl0, dl1, dl2, e0, e1, e2 = dlam[0], dlam[1], dlam[2], d2lam[0], d2lam[1], d2lam[2]
    o0, o1, g0, g1 = outer[0], outer[1], douter[0], douter[1]
    if cold:  # lfilter's y[-1] = w[0] / (1 - lam)
        u0 = fc[0] - h_rest[0] * length
        ya = (q00 * u0 + q01 * fm[0]) / (1.0 - lam0)
        yb = (q10 * u0 + q11 * fm[0]) / (1.0 - lam1)
    else:
        ya, yb = y_start[0], y_start[1]
    xa = v00 * ya + v01 * yb  # x before the block: linear_mmf's backward difference starts there
    xb = v10 * ya + v11 * yb
    pd0, pd1, pe0, pe1 = prev_drop[0], prev_drop[1], prev_drop[2], prev_drop[3]
    for k in range(n):
        u0 = fc[k] - h_rest[k] * length
        u1 = fm[k]
        ya = lam0 * ya + (q00 * u0 + q01 * u1)
        yb = lam1 * yb + (q10 * u0 + q11 * u1)
        x0 = v00 * ya + v01 * yb
        x1 = v10 * ya + v11 * yb
        dx0 = (x0 - xa) * fs_hz
        dx1 = (x1 - xb) * fs_hz
        s0 = u0 - (n00 * x0 + d00 * dx0)  # u - (N x + D dx/dt)
        s1 = u1 - d11 * dx1
        xa, xb = x0, x1
        f = -0.5 * (dl0 * (s0 * s0) + 2.0 * dl1 * s0 * s1 + dl2 * (s1 * s1))
        phi = o0 * s0 + o1 * s1
        if compliance != 0.0:
            dz = -f * compliance  # the gap closes as the load cell yields
            f = f + -0.5 * (e0 * (s0 * s0) + 2.0 * e1 * s0 * s1 + e2 * (s1 * s1)) * dz
            phi = phi + (g0 * s0 + g1 * s1) * dz
        force[k] = f
        flux[k] = phi
        iron_b[k] = x0
        r0 = fc[k] - s0  # the MMF drops; their rate a causal second-order backward difference
        r1 = u1 - s1
        if pd0 != pd0:  # NaN: the rig's first sample
            q0, q1 = 0.0, 0.0
        elif pe0 != pe0:  # its second: a first-order difference
            q0, q1 = (r0 - pd0) * fs_hz, (r1 - pd1) * fs_hz
        else:
            q0 = (3.0 * r0 - 4.0 * pd0 + pe0) * (0.5 * fs_hz)
            q1 = (3.0 * r1 - 4.0 * pd1 + pe1) * (0.5 * fs_hz)
        dflux[k] = o0 * (turns * dcur[k] - q0) + o1 * (dfm - q1)
        pe0, pe1, pd0, pd1 = pd0, pd1, r0, r1
    prev_drop[0], prev_drop[1], prev_drop[2], prev_drop[3] = pd0, pd1, pe0, pe1
    lag_end[0], lag_end[1], lag_end[2], lag_end[3] = ya, yb, xa, xb


#: solve_sequential's bounds: F evaluations for one sample (the Illinois steps at least halve a
#: bracket every third step: 300 close any bracket to neighbouring doubles), and the residual at
#: which a sample counts as solved (tesla of B, relative to the sample's B without remainder, at
#: least 1 T: ~2e-7 A/m of the iron's remainder, where the passes leave ~1e-3 of it)
MAX_EVALS, RESIDUAL_T = 300, 1e-11


@njit(cache=True, nogil=True, inline="always")
def _anhysteretic_slope(b, tabs, an):
    """dH/dB of the anhysteretic table at b: its segment's slope (1/s_end beyond its end)."""
    step = tabs[10]
    x = abs(b) / step
    i = int(min(x, an.size - 1.0))
    if i >= an.size - 1:
        return 1.0 / tabs[6]
    return (an[i + 1] - an[i]) / step


@njit(cache=True, nogil=True)
def solve_sequential(fc: np.ndarray, fm: np.ndarray, h_rest: np.ndarray, lag: np.ndarray, y_start: np.ndarray,
                     cold: bool, c_in: np.ndarray, c_out: np.ndarray, state0: np.ndarray, tin: np.ndarray,
                     tout: np.ndarray, end: np.ndarray, tabs: np.ndarray, psi: np.ndarray, virg: np.ndarray,
                     an: np.ndarray, mode: np.ndarray, nu0: float, length: float, rest_before: float,
                     out: np.ndarray) -> None:
    """The block's iron remainder solved sample by sample, for blocks whose passes do not converge.

    Why it converges where the passes do not: given everything before it, a sample's B is one
    unknown.  The linear part (nu0, eddy currents, magnet) makes B affine in this sample's
    remainder, B = c - G L h_rest (G: this sample's dB/dMMF), so the sample solves

        F(B) = (1 - G L nu0) B + G L H(B) - c = 0,

    where H is the iron's operator from its committed state: continuous and non-decreasing in B on
    each branch and where a loop is wiped out (a reversal starts a branch at the last point; each
    branch meets the turning point it returns to, hysteresis._closure).  alpha = 1 - G L nu0 > 0, so F rises
    at least alpha per tesla: a step of -F/alpha reaches or passes the root, which brackets it
    however steep the iron (saturation: dH/dB -> 1/mu0) and however far the current jumped.  The
    first trial is B with the remainder extrapolated from the last two samples (``rest_before``: the
    one before the block's last, NaN if unknown), the second the secant through it and the last
    sample (the branch's own chord, a reversal's too); regula falsi with the Illinois halving
    closes the bracket.  Every trial follows from the samples before it, never from the passes'
    iterate, so any cut of the stream into blocks gives the same samples (to the residual).

    Writes h_rest (the remainder per sample, as the final run takes it), the iron's state at the
    block's end as :func:`passes` does (end, tin/tout), and out = (F evaluations, largest residual
    |F| / (G L) in A/m, max |B| in T, samples left unsolved).  The residual is ~1e-9 A/m (where
    rounding leaves a step of H at the root, that step); a sample is unsolved only if its bracket
    did not close within MAX_EVALS (never seen)."""
    n = fc.size
    lam0, lam1, q00, q01, q10, q11, v00, v01 = lag[0], lag[1], lag[2], lag[3], lag[4], lag[5], lag[6], lag[7]
    irreversible, saturation = mode[0] != 0, mode[1] != 0
    nst, u_prev, y_prev, d, s, br = start_state(c_in, c_out, state0, tin, tout, tabs, psi, virg)
    # the committed point as this sample's operator gives it (no reversal, nothing wiped out)
    committed = iron_at(u_prev, u_prev, y_prev, d, nst, tin, tout, s, br, tabs, psi, virg, an, irreversible,
                         saturation)
    h_prev = committed[1]
    rest2 = rest_before  # the remainder two samples back
    ya, yb = y_start[0], y_start[1]
    evals, worst, peak, unsolved = 0, 0.0, 0.0, 0
    for k in range(n):
        u1 = fm[k]
        if k == 0 and cold:  # final_run's start: y[-1] = w[0] / (1 - lam), so y[0] = w[0] / (1 - lam)
            pa, ga = q01 * u1 / (1.0 - lam0), q00 / (1.0 - lam0)
            pb, gb = q11 * u1 / (1.0 - lam1), q10 / (1.0 - lam1)
        else:
            pa, ga = lam0 * ya + q01 * u1, q00
            pb, gb = lam1 * yb + q11 * u1, q10
        g = v00 * ga + v01 * gb  # dB / d(coil MMF) at this sample
        gl = g * length
        alpha = 1.0 - gl * nu0
        c = v00 * pa + v01 * pb + g * fc[k]  # B with no remainder
        tol = RESIDUAL_T * max(1.0, abs(c))
        best = committed
        b_best = u_prev
        f_best = alpha * u_prev + gl * h_prev - c
        # the bracket: lo (F < 0) and hi (F > 0), with F as Illinois scales it
        has_lo, has_hi = f_best < 0.0, f_best > 0.0
        lo, flo, hi, fhi = u_prev, f_best, u_prev, f_best
        rest1 = h_prev - nu0 * u_prev  # the last sample's remainder
        x = c - gl * (2.0 * rest1 - rest2 if rest2 == rest2 else rest1)  # extrapolated (NaN: none)
        side, trial, closed = 0, 0, abs(f_best) <= tol
        while not closed and trial < MAX_EVALS:
            res = iron_at(x, u_prev, y_prev, d, nst, tin, tout, s, br, tabs, psi, virg, an, irreversible,
                           saturation)
            fx = alpha * x + gl * res[1] - c
            trial += 1
            if abs(fx) < abs(f_best):
                b_best, f_best, best = x, fx, res
            if abs(fx) <= tol:
                break
            if fx < 0.0:  # Illinois: the side kept twice in a row has its F halved
                if side == -1 and has_hi:
                    fhi *= 0.5
                lo, flo, has_lo, side = x, fx, True, -1
            else:
                if side == 1 and has_lo:
                    flo *= 0.5
                hi, fhi, has_hi, side = x, fx, True, 1
            if trial == 1:  # the secant through the committed point: the branch's own chord
                f0 = alpha * u_prev + gl * h_prev - c
                if fx != f0 and x != u_prev:
                    nxt = x - fx * (x - u_prev) / (fx - f0)
                else:  # (a standstill) a Newton step with the anhysteretic slope
                    nxt = x - fx / (alpha + gl * _anhysteretic_slope(x, tabs, an))
                if not (has_lo and has_hi) or min(lo, hi) < nxt < max(lo, hi):
                    x = nxt
                    continue
            if not (has_lo and has_hi):  # F rises at least alpha per tesla: -F/alpha reaches the root
                x = x - fx / alpha * (1.0 if trial < 8 else 2.0 ** (trial - 7))  # (more if H steps down)
                continue
            x = (lo * fhi - hi * flo) / (fhi - flo)
            if not min(lo, hi) < x < max(lo, hi):  # rounding in a tiny bracket: its middle
                x = 0.5 * (lo + hi)
                if not min(lo, hi) < x < max(lo, hi):
                    # neighbouring doubles: the root is a step of H (a rounding-level step where
                    # a loop is wiped out); the residual is that step
                    closed = True
        if not closed and abs(f_best) > tol:
            unsolved += 1
        evals += trial
        worst = max(worst, abs(f_best) / gl)
        peak = max(peak, abs(b_best))
        y, h, d, nst, s, br = best
        committed = best
        u_prev, y_prev, h_prev = b_best, y, h
        rest2 = rest1
        hr = h - nu0 * b_best
        h_rest[k] = hr
        u0 = fc[k] - hr * length
        if k == 0 and cold:
            ya = (q00 * u0 + q01 * u1) / (1.0 - lam0)
            yb = (q10 * u0 + q11 * u1) / (1.0 - lam1)
        ya = lam0 * ya + (q00 * u0 + q01 * u1)
        yb = lam1 * yb + (q10 * u0 + q11 * u1)
    end[0], end[1], end[2], end[3] = u_prev, y_prev, d, nst
    out[0], out[1], out[2], out[3] = evals, worst, peak, unsolved


#: ``rate`` of a rig without rate terms: nothing added, nothing damped
NO_RATE = np.zeros(9)
#: ``scale`` of an iron whose static field does not drift (no iron_thermal_drift)
NO_SCALE = np.zeros(0)


def rate_terms(excess: tuple[float, float] | None, relaxation: tuple[float, float] | None, fs_hz: float,
               b_before: float, b_slow_before: float) -> np.ndarray:
    """The kernels' ``rate``: (excess on, k, r0, relaxation on, a = exp(-1/(tau fs)), kappa, fs, B and B_slow
    at the sample before the block)."""
    k, r0 = excess if excess is not None else (0.0, 0.0)
    tau, kappa = relaxation if relaxation is not None else (1.0, 0.0)
    return np.array([excess is not None, k, r0, relaxation is not None, math.exp(-1.0 / (tau * fs_hz)), kappa, fs_hz,
                     b_before, b_slow_before], dtype=np.float64)
