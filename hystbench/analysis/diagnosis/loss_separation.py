"""The diagnosis on measured material tables (core loss, or complex permeability) instead of sweeps.

A table gives the energy per cycle and volume W(f, B) = P/f of a core under a sinusoidal flux
density of peak B at frequency f.  Our static hysteresis is rate independent: its W depends on B
only.  The procedure is issue 13's, on W instead of waveforms:

1. Calibrate the baseline, a rate-independent W_h(B) = k_h (B/B0)^beta exp(c ln^2(B/B0)), B0 = 0.1 T,
   on the lowest frequencies (``low_third``: the lowest third of the frequency bins; the rest held
   out) or on an ``interleaved`` split (the lowest fifth plus every 3rd bin).  The curvature c lets a
   Preisach-like W(B) bend (Rayleigh region to saturation) so that a B shape is not mistaken for a
   rate dependence; it is still rate independent.  Fits are in log space (the tables span 4 decades).
2. Locate: the held-out residual log10(W_measured / W_baseline) on a frequency x flux-density grid,
   each cell a z-score against sqrt(noise^2/n + model^2): ``noise`` is the measurement scatter,
   estimated from the table itself (the rms deviation of each frequency's points from a smooth
   quadratic in log B through them: neighbouring points, no model of f), ``model`` the baseline's
   rms misfit where it was calibrated (a baseline merely imperfect raises no alarm).  The trend:
   the residual's slope in log f (energy per cycle growing with f) and in log B.
3. Name: forward selection by BIC on the calibration points over the term library
   (:mod:`.loss_terms`), in three tiers: Bertotti's fixed forms, the classical term (the catalogue's
   ``lamination_eddy_currents``: H_e = sigma d^2/12 dB/dt gives W_cl = pi^2 sigma d^2 f B^2 / 6; in a
   ferrite the bulk eddy-current / relaxation analogue) and the excess term k_e f^0.5 B^1.5 (the
   catalogue's ``excess_loss``); then the generic forms with their orders in the rate fixed (a series
   of the dynamic field in dB/dt, a first-order relaxation after ramps into flat segments, a
   temperature factor, a loss per cycle falling with f); last a free power law in f, B and dB/dt; each
   generic term reported as "not in the catalogue: <form> with <parameters>".  A term is taken only
   when better than the current model by >= 10 and than the runner-up by >= 6, when its size is
   determined (its energy at 100 kHz
   and 0.1 T beyond two standard errors; in the model without an earlier term it makes redundant, if
   there is one), and when, fitted on the split's own rule inside the calibration rows, it predicts
   the rest of them better (else a suspect); a generic term that makes earlier ones redundant drops
   them, and one refused on top of an earlier generic term replaces it where it is decisively better
   in its place, its size determined and no exponent on a bound.
4. Model: the parameters with standard errors from the fit's covariance (Jacobian, scaled by the
   residual variance), in natural units by the delta method.
5. Prove: held-out rms log10 error before (baseline) and after (baseline + named terms), in units
   of the noise floor, and their ratio.

Non-sinusoidal flux (MagNet's triangles and trapezoids, a ``_shapes`` table read with the sine table
of the same material: :func:`diagnose_loss_table` takes several tables, :func:`loss_table_groups`
says which go together): B(t) = B_pk b(t/T), and each rate term k f^gamma B^delta is multiplied by
its shape factor S_p, p = 1 + gamma (:mod:`.loss_shapes`: Bertotti's separation carried to arbitrary
waveforms, the iGSE's for the free term; S_p = 1 for a sine, so a sine table's figures are unchanged);
the rate-independent W_h(B_pk) stays the baseline (the same excursion for every shape).  The
baseline is calibrated on the sine rows and the symmetric triangles (duty 0.5, 0, 0.5, 0) of the
calibration frequencies; every other shape at every frequency is held out.  Located and proved per
duty shape and per group (sine, triangle, trapezoid) as well.  Losses between the ramps (relaxation)
can be fitted only where flat segments are calibrated on (``calibrate_on="all_shapes"``); otherwise
they show as a residual growing with the share duty_2 + duty_4.
"""

from __future__ import annotations

import copy
import hashlib
import math
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

import numpy as np
from scipy.constants import mu_0
from scipy.optimize import least_squares
from threadpoolctl import threadpool_limits

from ...errors import EstimationError, RecordingError, script_status
from ...formats.material_data import LossTable, read_material_table
from .loss_shapes import calibration_shapes, locate_shapes
from .loss_terms import (B0_T, FREE_BOUNDS, LIBRARY, STEINMETZ, TERMS, TIERS, Rows, Term, form, inert, n_params, natural,
                         term_bounds, term_gradient, term_part, term_start, term_starts)

__all__ = ["TERMS", "Term", "TermFit", "bic", "energy_per_cycle", "SPLITS", "split_mask", "fit_terms", "noise_floor",
           "calibrate_split", "log_energy", "select_on_split", "energy_table", "diagnose_energy", "diagnose_loss_table", "loss_table_groups", "rate_trend", "main"]

NAME_DELTA_BIC = 10.0  # decisively better than the current model (issue 13)
NOISE_FLOOR_MIN_LOG10 = 1e-12  # the scatter of a table written to 12 digits
RUNNER_UP_DELTA_BIC = 6.0  # and than the runner-up
LN10 = math.log(10.0)
MAX_TERMS = 3  # rate terms a model may take
#: Calibration rows below which a split cannot decide a rate term (refused where triangles and
#: trapezoids are calibrated; on a sine table the verdict says so).
MIN_DECIDING_ROWS = 12
MAX_SCALE_REL_STD = 0.5  # a term is taken only when its scale is fitted beyond two standard errors


def bic(rss: float, n: int, k: int) -> float:
    """The likelihood rule's score of a least-squares fit in log space: k parameters, n rows."""
    return n * math.log(max(rss, 1e-300) / n) + k * math.log(n)


@dataclass(frozen=True)
class TermFit:
    """One model fitted in log space on the calibration points."""

    terms: tuple[Term, ...]
    x: np.ndarray  # [ln k_h, beta, c, then per term its n_params values]
    cov: np.ndarray
    rss: float  # sum of squared ln residuals on the calibration points
    n: int
    #: per parameter: in a direction the rows do not determine, which the covariance's pseudo-inverse
    #: cuts off (it reported a term on its energy floor as "1.0e-09 +- 1.4e-19"): no standard error
    undetermined: np.ndarray | None = None

    @property
    def bic(self) -> float:
        return bic(self.rss, self.n, self.x.size)

    def log_w(self, f: np.ndarray, b: np.ndarray, duty: np.ndarray | None = None,
              temperature_c: np.ndarray | None = None) -> np.ndarray:
        return log_energy(self.x, self.terms, Rows(f, b, duty, temperature_c))

    def parameters(self) -> dict[str, dict[str, tuple[float, float]]]:
        """Effect -> parameter -> (value, std), natural units (delta method from the ln-k covariance)."""
        se = np.sqrt(np.maximum(np.diag(self.cov), 0.0))
        if self.undetermined is not None:
            se[self.undetermined] = math.nan
        kh = math.exp(self.x[0])
        out = {"static_hysteresis": {"k_h_J_per_m3_at_0.1T": (kh, kh * se[0]), "beta": (self.x[1], se[1]),
                                     "curvature": (self.x[2], se[2])}}
        i = 3
        for t in self.terms:
            k = n_params(t)
            out[t.name] = natural(t, self.x[i:i + k], se[i:i + k])
            i += k
        return out


def energy_per_cycle(table: LossTable, *, shapes: bool = False) -> np.ndarray:
    """W (J/m^3 per cycle) of every row.  MagNet's triangular/trapezoidal rows are refused unless
    ``shapes`` (the caller then carries ``table.duty`` into the fit: a W read as a sine's is wrong).

    Core loss: W = P / f.  Complex permeability: with B = Re(B_pk e^{jwt}) and H = B/(mu_0 mu_r),
    W = (closed integral of H dB) = pi Im(H_pk conj(B_pk)) = pi B_pk^2 Im(1/mu_r) / mu_0
    = pi B_pk^2 mu'' / (mu_0 |mu_r|^2) for mu_r = mu' - j mu'' (``mu_imag = -mu''``).
    """
    f, b = table.frequency_hz, table.flux_density_t
    shaped = int(np.count_nonzero(table.duty[:, 0] != -1))
    if shaped and not shapes:  # a loss at a triangle's or trapezoid's B(t) is not the sine's the terms below describe
        raise RecordingError(f"{table.path}: {shaped} of {len(f)} rows are not sinusoidal (duty_1 != -1: MagNet's "
                             "triangular or trapezoidal flux); the loss separation models a sinusoidal flux only")
    if table.kind == "core_loss":
        return table.columns["loss_W_per_m3"] / f
    mu = table.columns["mu_real"] + 1j * table.columns["mu_imag"]
    return np.pi * b**2 * (-mu.imag) / (mu_0 * np.abs(mu) ** 2)


#: Which of a table's distinct frequencies each split calibrates at, in words (the rest is held out).
SPLITS = {"low_third": "lowest third", "interleaved": "lowest fifth + every third"}


def split_mask(f: np.ndarray, how: str) -> np.ndarray:
    """Calibration rows: ``low_third`` (the lowest third of the distinct frequencies, at least three)
    or ``interleaved`` (the lowest fifth plus every 3rd frequency).  Why three: a rate term's
    frequency dependence is not fitted from fewer (on one frequency every rate term is a constant,
    and "nothing needed" would be said of what cannot be seen there); and one frequency at least is
    held out."""
    bins = np.unique(f)
    if how == "low_third":
        cal = bins[:max(bins.size // 3, 3)]
    elif how == "interleaved":
        cal = np.union1d(bins[:max(bins.size // 5, 1)], bins[::3])
    else:
        raise EstimationError(f"split {how!r}: choose low_third or interleaved")
    if cal.size < 3 or cal.size >= bins.size:
        raise EstimationError(f"split {how!r}: the table has {bins.size} distinct frequencies; calibrating a rate "
                              "term's frequency dependence needs 3 of them and one more to hold out"
                              + ("" if how == "low_third" else " (the interleaved split takes every third: 7 or more)"))
    return np.isin(f, cal)


def log_energy(x: np.ndarray, terms: Sequence[Term], rows: Rows) -> np.ndarray:
    """ln W: the rate-independent baseline plus every energy term (with ``rows.duty`` each rate term
    scaled by its shape factor), times the temperature factor when there is one."""
    lb = rows.ln_b - math.log(B0_T)
    parts = [x[0] + x[1] * lb + x[2] * lb**2]
    factor = 0.0
    i = 3
    for t in terms:
        k = n_params(t)
        part = term_part(t, x[i:i + k], rows)
        if t.kind == "temperature":
            factor = factor + part
        else:
            parts.append(part)
        i += k
    return np.logaddexp.reduce(np.stack(parts), axis=0) + factor


def log_energy_jacobian(x: np.ndarray, terms: Sequence[Term], rows: Rows) -> np.ndarray:
    """d :func:`log_energy` / dx, (rows, x.size): each energy's gradient weighted by its share of W."""
    lb = rows.ln_b - math.log(B0_T)
    parts = [x[0] + x[1] * lb + x[2] * lb**2]
    grads = [np.column_stack([np.ones_like(lb), lb, lb**2])]
    factor = []  # the temperature factor's columns: it multiplies W, its gradient adds
    i = 3
    for t in terms:
        k = n_params(t)
        g = term_gradient(t, x[i:i + k], rows)
        if t.kind == "temperature":
            factor.append((i, g))
        else:
            parts.append(term_part(t, x[i:i + k], rows))
            grads.append((i, g))
        i += k
    stacked = np.stack(parts)
    share = np.exp(stacked - np.logaddexp.reduce(stacked, axis=0))  # 0 where a part is -inf
    jac = np.zeros((rows.f.size, x.size))
    jac[:, :3] = share[0][:, None] * grads[0]
    for s, (j, g) in zip(share[1:], grads[1:]):
        jac[:, j:j + g.shape[1]] = s[:, None] * g
    for j, g in factor:
        jac[:, j:j + g.shape[1]] = g
    return jac


def fit_terms(f: np.ndarray, b: np.ndarray, w: np.ndarray, terms: Sequence[Term] = (),
              duty: np.ndarray | None = None, temperature_c: np.ndarray | None = None,
              start: TermFit | None = None) -> TermFit:
    """Baseline + ``terms`` fitted to ln W by least squares, from several starts (each term starting
    at 1 %, 10 % and 50 % of the median energy, and at two exponents or time constants where free;
    with ``start``, a fit of the same rows with ``terms[:-1]``, from it and the last term at 3 % and
    30 %, and cold at 10 %); the Jacobian in closed form (:func:`log_energy_jacobian`); the covariance is
    (J'J)^-1 rss/dof.  ``duty``: the rows' MagNet duties (None: all sines)."""
    rows = Rows(f, b, duty, temperature_c)
    y = np.log(w)
    lb = np.log(b / B0_T)
    base = np.linalg.lstsq(np.column_stack([np.ones_like(lb), lb, lb**2]), y, rcond=None)[0]
    best = None
    energy = [t for t in terms if t.kind != "temperature"]
    second = [term_starts(t) for t in terms]
    n_starts = max((len(s) for s in second), default=1)
    warm = start is not None and start.terms == tuple(terms[:-1])
    cold = [(s, False) for s in ((0.1,) if warm else (0.01, 0.1, 0.5) if energy else (1.0,))]
    # from the model so far, when there is one (where the new term most often belongs), and one cold start
    # beside it: on N49's sines only a cold start reached the free term's better optimum
    for share, from_start in ([(0.03, True), (0.3, True)] if warm else []) + cold:
        for j in range(n_starts):
            x0 = [base[0] + math.log(1.0 - share) if energy else base[0], base[1], base[2]]
            lo, hi = [-np.inf] * 3, [np.inf] * 3
            for t, s2 in zip(terms, second):
                x0 += term_start(t, y, rows, share, s2[min(j, len(s2) - 1)])
                tl, th = term_bounds(t)
                lo += tl
                hi += th
            if from_start:  # the model so far as fitted, its energy scaled down to make room for the new term
                x0[:start.x.size] = list(start.x)
                if terms[-1].kind != "temperature":
                    x0[0] += math.log(1.0 - share)
            x0 = np.clip(np.array(x0), np.array(lo) + 1e-9, np.array(hi) - 1e-9)
            sol = least_squares(lambda x: log_energy(x, terms, rows) - y, x0, bounds=(lo, hi), x_scale="jac",
                                tr_solver="exact", jac=lambda x: log_energy_jacobian(x, terms, rows))
            if best is None or sol.cost < best.cost:
                best = sol
    resid = best.fun
    dof = max(resid.size - best.x.size, 1)
    cov = np.linalg.pinv(best.jac.T @ best.jac, rcond=PINV_RCOND) * float(resid @ resid) / dof
    return TermFit(tuple(terms), best.x, cov, float(resid @ resid), int(resid.size), undetermined(best.jac))


#: The pseudo-inverse's cut-off (numpy's default, written out): J'J's directions below it are dropped.
PINV_RCOND = 1e-15


def undetermined(jac: np.ndarray) -> np.ndarray:
    """Per parameter: mostly in the directions pinv(J'J) cuts off (J's singular values below
    sqrt(PINV_RCOND) of its largest), where the rows do not determine it and the covariance says ~0."""
    _, s, vt = np.linalg.svd(jac, full_matrices=False)
    lost = s < s[0] * math.sqrt(PINV_RCOND)
    return (vt[lost] ** 2).sum(axis=0) > 0.5


def noise_floor(f: np.ndarray, b: np.ndarray, w: np.ndarray, duty: np.ndarray | None = None) -> float:
    """The measurement scatter (rms, log10 units) from the table alone: at each frequency (and duty
    shape) with >= 6 points, the deviations from a quadratic in log B through them, pooled with their
    degrees of freedom.  It holds repeatability and any roughness finer than a quadratic; no model of f.
    A table with no such frequency (every row at its own frequency, or a sparse grid) gets the scatter
    about a smooth surface in log f and log B per shape instead: an upper bound, as the surface's own
    misfit is in it.  Never below :data:`NOISE_FLOOR_MIN_LOG10` (a table computed, not measured)."""
    return _about_neighbours(f, b, w, duty, np.ones(f.size, bool))[1]


def _about_neighbours(f: np.ndarray, b: np.ndarray, w: np.ndarray, duty: np.ndarray | None,
                      keep: np.ndarray) -> tuple[np.ndarray, float, np.ndarray, np.ndarray]:
    """Each row's log10 deviation from the smooth curve of its neighbours (:func:`noise_floor`'s fits,
    through the ``keep`` rows only, each kept row's as if it were left out, so that a row at the end of
    a curve cannot bend it onto itself; NaN where a row has too few, or where it alone sets a direction
    of its curve), the pooled rms of the kept rows, which curve each row is on, and by how much each
    kept row's removal would lower its curve's sum of squares (r^2 / (1 - h): which row of a curve is
    the bad one, where the leave-one-out deviations of its neighbours at the curve's end are pulled as
    far)."""
    y, lb = np.log10(w), np.log10(b)
    group = _groups(f[:, None] if duty is None else np.column_stack([f, duty]))
    u = _standardised(lb, group, keep)
    deleted, gain, ss, dof = _fit_per_group(np.column_stack([np.ones_like(u), u, u**2]), y, group, keep, 6)
    if dof == 0:  # a sparse or off-grid table: the scatter about a smooth surface per shape, an upper bound
        group = _groups(np.zeros((f.size, 1)) if duty is None else duty)
        u, v = _standardised(lb, group, keep), _standardised(np.log10(f), group, keep)
        surface = np.column_stack([np.ones_like(u), v, v**2, u, u**2, u**3, u * v])
        deleted, gain, ss, dof = _fit_per_group(surface, y, group, keep, 14)
    if dof == 0:
        raise EstimationError("noise floor: neither 6 flux densities at one frequency nor 14 rows of one shape "
                              "to measure the scatter on")
    return deleted, max(math.sqrt(ss / dof), NOISE_FLOOR_MIN_LOG10), group, gain


def _groups(keys: np.ndarray) -> np.ndarray:
    """Each row's group: an index per distinct row of ``keys``."""
    return np.unique(keys, axis=0, return_inverse=True)[1].ravel()


#: Below this spread (log10 units) a group's values are one value: 0.3 and 0.1 * 3 are one flux density.
SAME_VALUE_LOG10 = 1e-9


def _standardised(values: np.ndarray, group: np.ndarray, keep: np.ndarray) -> np.ndarray:
    """``values`` centred and scaled per group on its kept rows (centred only where they are one value,
    :data:`SAME_VALUE_LOG10`): polynomials in them span what polynomials in ``values`` do, better
    conditioned."""
    n = int(group.max()) + 1
    count = np.maximum(np.bincount(group, weights=keep.astype(float), minlength=n), 1.0)
    centred = values - (np.bincount(group, weights=keep * values, minlength=n) / count)[group]
    scale = np.sqrt(np.bincount(group, weights=keep * centred**2, minlength=n) / count)
    return centred / np.where(scale > SAME_VALUE_LOG10, scale, 1.0)[group]


#: A direction of a group's columns is lost (the rows do not span it) below this share of the column's
#: norm, as numpy's least squares would drop it (one flux density on a curve: a constant).
LOST_DIRECTION = 1e-10
#: A row that alone sets a direction of its group's fit (1 - h below this) is predicted by nothing else:
#: it is not judged (r / (1 - h) is 0 / 0, and rounding made good rows gross errors).
ALONE = 1e-6


def _fit_per_group(x: np.ndarray, y: np.ndarray, group: np.ndarray, keep: np.ndarray,
                   least: int) -> tuple[np.ndarray, np.ndarray, float, int]:
    """:func:`_about_neighbours`'s fits: per group with ``least`` kept rows or more, ``y`` by least squares
    on the columns ``x`` (rows, k) through its kept rows.  Each row's deviation, a kept row's as if it were
    left out (r / (1 - h)), NaN in a group with too few and where the row is :data:`ALONE`; the fall of its
    group's sum of squares without it (r^2 / (1 - h), judged rows only); the kept rows' sum of squares and
    degrees of freedom (rows - k per group).  Every group at once: the columns orthogonalised per group
    on its kept rows (Gram-Schmidt, twice, the inner products by ``bincount``), so that the fit and the
    hat matrix's diagonal are sums over orthogonal directions."""
    n = int(group.max()) + 1
    kept = keep.astype(float)

    def dot(a: np.ndarray, c: np.ndarray) -> np.ndarray:  # per group, over its kept rows
        return np.bincount(group, weights=kept * a * c, minlength=n)

    count = dot(np.ones_like(y), np.ones_like(y))
    basis: list[tuple[np.ndarray, np.ndarray]] = []  # (column orthogonal to the ones before, its squared norm)
    for j in range(x.shape[1]):
        q = x[:, j].astype(float)
        size = np.maximum(dot(q, q), count)  # standardised columns: about the rows' count, or ~0 for one value
        for _ in range(2):
            for p, norm in basis:
                q = q - (dot(p, q) / np.where(norm > 0, norm, 1.0))[group] * p
        norm = dot(q, q)
        lost = norm <= size * LOST_DIRECTION**2
        basis.append((np.where(lost[group], 0.0, q), np.where(lost, 0.0, norm)))
    fit, leverage = np.zeros_like(y), np.zeros_like(y)
    for p, norm in basis:
        safe = np.where(norm > 0, norm, 1.0)
        fit += (dot(p, y) / safe)[group] * p
        leverage += p**2 / safe[group]
    fitted = (count >= least)[group]
    r = np.where(fitted, y - fit, np.nan)
    inside = fitted & keep
    judged = inside & (1.0 - leverage > ALONE)
    deleted = np.where(inside, np.nan, r)  # a dropped row: its deviation from the kept rows' curve
    deleted[judged] = r[judged] / (1.0 - leverage[judged])
    gain = np.full_like(r, np.nan)
    gain[judged] = r[judged] ** 2 / (1.0 - leverage[judged])
    return deleted, gain, float(np.sum(r[inside] ** 2)), int(np.sum(count[count >= least] - x.shape[1]))


#: A row is a gross error (a mistyped value, a row in another unit), not a measurement, when it lies
#: off its neighbours' smooth curve by more than a factor of two and by more than this many times the
#: table's scatter (robust: 1.4826 median absolute deviations).  MagNet's vendored tables lie within a
#: factor of 1.8.
OUTLIER_FACTOR, OUTLIER_RMS = 2.0, 9.0
#: Removals that lower a curve's sum of squares alike to this share are a tie (rounding decides them).
TIED_GAIN = 1e-9
#: More rows than this share (and more than two) so far off are the table's own shape (or a column in
#: another unit), not glitches.
MAX_OUTLIER_SHARE = 0.02


def gross_outlier_rows(f: np.ndarray, b: np.ndarray, w: np.ndarray, duty: np.ndarray | None = None) -> np.ndarray:
    """The rows far off their neighbours (:data:`OUTLIER_FACTOR`, :data:`OUTLIER_RMS`); a boolean mask.
    Backward deletion: per pass, on each curve with a row beyond both, the row whose removal lowers the
    curve's sum of squares most is left out, and the curves are refitted without it, until no row is
    beyond: a bad row pulls its neighbours' curves towards it, so judged all at once they would go with
    it (a short curve then had too few rows left to be judged at all)."""
    out = np.zeros(f.size, bool)
    while out.sum() <= _most_outliers(f.size):  # beyond it the table is refused: no need to find every one
        r, _, curve, gain = _about_neighbours(f, b, w, duty, ~out)
        judged = np.isfinite(r) & ~out
        if not judged.any():
            break
        off = judged & (np.abs(r) > _too_far(r[judged]))
        if not off.any():
            break
        # per curve, the row whose removal helps most; among rows that help as much (to rounding: two single
        # rows at their own flux densities, either of which leaves a quadratic), the one furthest off
        worst = np.where(judged, gain, -1.0)
        most = np.full(int(curve.max()) + 1, -1.0)
        np.maximum.at(most, curve, worst)
        rank = np.where(judged & (worst >= most[curve] * (1.0 - TIED_GAIN)), np.abs(r), -1.0)
        order = np.lexsort((-rank, curve))
        first = order[np.r_[True, curve[order][1:] != curve[order][:-1]]]
        hit = np.isin(curve[first], curve[off])
        out[first[hit & judged[first]]] = True
    # two bad rows side by side bend their curve onto a good neighbour, which may go first: each row left
    # out is judged once more against the curve of the rows kept, and taken back where it lies on it
    r, _, _, _ = _about_neighbours(f, b, w, duty, ~out)
    judged = np.isfinite(r) & ~out
    if judged.any():
        out &= ~(np.isfinite(r) & (np.abs(r) <= _too_far(r[judged])))
    return out


def screened(f: np.ndarray, b: np.ndarray, w: np.ndarray, duty: np.ndarray | None = None,
             temperature_c: np.ndarray | None = None) -> tuple[np.ndarray, tuple[Any, ...]]:
    """The gross outliers' mask, and (f, b, w, duty, temperature_c) without them: what the diagnosis
    and its figures are computed on."""
    out = gross_outlier_rows(f, b, w, duty)
    keep = ~out
    return out, tuple(None if a is None else a[keep] for a in (f, b, w, duty, temperature_c))


def _too_far(deviations: np.ndarray) -> float:
    """How far off (log10) a row is a gross error, given the deviations of the rows judged."""
    return max(OUTLIER_RMS * 1.4826 * float(np.median(np.abs(deviations))), math.log10(OUTLIER_FACTOR))


def _most_outliers(rows: int) -> float:
    """More rows so far off are the table itself (:data:`MAX_OUTLIER_SHARE`, and more than two)."""
    return max(MAX_OUTLIER_SHARE * rows, 2.0)


def rate_trend(f: np.ndarray, b: np.ndarray, resid_log10: np.ndarray) -> dict[str, Any]:
    """The residual's slopes d log10(W_meas/W_model) / d log10 f and / d log10 B, with standard errors:
    > 0 in f means energy per cycle grows with frequency beyond the model."""
    a = np.column_stack([np.ones_like(f), np.log10(f / np.median(f)), np.log10(b / B0_T)])
    coef, *_ = np.linalg.lstsq(a, resid_log10, rcond=None)
    r = resid_log10 - a @ coef
    cov = np.linalg.pinv(a.T @ a) * float(r @ r) / max(r.size - 3, 1)
    se = np.sqrt(np.diag(cov))
    return {"slope_log_f": float(coef[1]), "slope_log_f_std": float(se[1]),
            "slope_log_B": float(coef[2]), "slope_log_B_std": float(se[2])}


def _locate(f: np.ndarray, b: np.ndarray, resid: np.ndarray, held: np.ndarray, noise: float,
            model: float) -> dict[str, Any]:
    """The held-out residual (log10) on a grid of up to 8 frequency x 6 flux-density bins, z-scored."""
    fe = np.unique(np.quantile(f[held], np.linspace(0, 1, min(8, np.unique(f[held]).size) + 1)))
    if fe.size < 2:  # one frequency held out (a table of four): one bin of it
        fe = np.repeat(fe, 2)
    be = np.quantile(b[held], np.linspace(0, 1, 7))
    fi = np.clip(np.searchsorted(fe, f[held], side="right") - 1, 0, fe.size - 2)
    bi = np.clip(np.searchsorted(be, b[held], side="right") - 1, 0, be.size - 2)
    mean = np.full((fe.size - 1, be.size - 1), np.nan)
    z = np.full_like(mean, np.nan)
    count = np.zeros(mean.shape, dtype=int)
    for i in range(mean.shape[0]):
        for j in range(mean.shape[1]):
            m = (fi == i) & (bi == j)
            if m.any():
                count[i, j] = int(m.sum())
                mean[i, j] = float(resid[held][m].mean())
                z[i, j] = mean[i, j] / math.sqrt(noise**2 / m.sum() + model**2)
    trend = rate_trend(f[held], b[held], resid[held])
    return {"frequencies_Hz": [float(x) for x in np.sqrt(fe[:-1] * fe[1:])],
            "flux_densities_T": [float(x) for x in np.sqrt(be[:-1] * be[1:])],
            "residual_log10": _nan_none(mean), "z": _nan_none(z), "count": count.tolist(),
            "max_abs_z": float(np.nanmax(np.abs(z))), "model_error_floor_log10": model, "trend": trend}


def _nan_none(a: np.ndarray) -> list:
    return [[None if not math.isfinite(v) else float(v) for v in row] for row in a]


def _rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(x**2)))


def _inner_split(f: np.ndarray, split: str) -> np.ndarray | None:
    """The split's own rule applied inside the calibration rows (None when they span < 3 frequencies)."""
    try:
        return split_mask(f, split)
    except EstimationError:
        return None


def _inner_proof(rows: Rows, w: np.ndarray, terms: tuple[Term, ...], term: Term, inner: np.ndarray | None
                 ) -> dict[str, float] | None:
    """Does ``term`` extrapolate within the calibration rows?  Fitted on the inner calibration rows with
    and without it, the rms log10 error on the other calibration rows (None when there is no inner split)."""
    if (inner is None or inner.sum() < 12 or np.unique(rows.f[inner]).size < 3
            or inert(term, rows.take(inner)) is not None):
        return None  # a rate term's f dependence is not fitted from fewer than 3 frequencies
    r_in, y = rows.take(inner), np.log10(w)
    out = {}
    for key, ts in (("without", terms), ("with", terms + (term,))):
        fit = fit_terms(r_in.f, r_in.b, w[inner], ts, r_in.duty, r_in.temperature_c)
        r = y[~inner] - log_energy(fit.x, ts, rows.take(~inner)) / LN10
        out[key] = _rms(r)
    return out


def _select(rows: Rows, w: np.ndarray, split: str = "low_third"
            ) -> tuple[list[TermFit], list[dict[str, Any]], list[str], list[dict[str, Any]], dict[str, str]]:
    """Forward selection over the library, tier by tier (:data:`.loss_terms.TIERS`: Bertotti's named
    forms first, then the generic ones on top of what they explain, a free exponent last): the best
    addition is taken while it beats the current model by >= NAME_DELTA_BIC and the runner-up by >=
    RUNNER_UP_DELTA_BIC, its size is determined (:data:`MAX_SCALE_REL_STD`), and, fitted on the
    split's own rule inside the calibration rows, predicts the other calibration rows better than the
    model without it (a decisive score is not enough: a term that explains the
    calibration window but extrapolates worse is a suspect, as in issue 13's selection).  Returns the
    fits after each step, the scored candidates, the chosen names, the suspects and the terms skipped
    as not identifiable on these rows (why)."""
    seq = [fit_terms(rows.f, rows.b, w, (), rows.duty, rows.temperature_c)]
    state: dict[str, Any] = {"chosen": [], "candidates": [], "suspects": [], "round": 0,
                             "skipped": {t.name: why for t in LIBRARY if (why := inert(t, rows)) is not None}}
    inner = _inner_split(rows.f, split)
    for tier in TIERS:
        pool = [t for t in tier if t.name not in state["skipped"]]
        while pool and len(state["chosen"]) < MAX_TERMS:
            taken = _round(rows, w, seq, pool, inner, state)
            if taken is None:
                break
            pool = [t for t in pool if t.name != taken]
            _drop_redundant(rows, w, seq, state)
    state["suspects"] += [{**d, "dropped": True} for d in state.get("dropped", [])]
    return seq, state["candidates"], state["chosen"], state["suspects"], state["skipped"]


def _drop_redundant(rows: Rows, w: np.ndarray, seq: list[TermFit], state: dict[str, Any]) -> None:
    """After a generic term is taken, an earlier term it makes redundant (the model without it within
    NAME_DELTA_BIC) is dropped: a free Steinmetz term can carry what a classical term was taken for,
    and the catalogue name must not stay on it by the order of the tiers.  One at a time, until none is."""
    dropped = True
    while dropped:
        dropped = False
        current = seq[-1]
        for t in current.terms[:-1]:
            kept = tuple(u for u in current.terms if u is not t)
            fit = fit_terms(rows.f, rows.b, w, kept, rows.duty, rows.temperature_c)
            if fit.bic - current.bic < NAME_DELTA_BIC:
                state["chosen"].remove(t.name)
                state["dropped"] = state.get("dropped", []) + [{"name": t.name, "delta_bic": fit.bic - current.bic}]
                seq.append(fit)
                dropped = True
                break


def _round(rows: Rows, w: np.ndarray, seq: list[TermFit], pool: list[Term], inner: np.ndarray | None,
           state: dict[str, Any]) -> str | None:
    """One round of forward selection over ``pool`` on top of ``seq[-1]``; the name taken, or None."""
    current = seq[-1]
    state["round"] += 1
    rnd = state["round"]
    fits = {t.name: fit_terms(rows.f, rows.b, w, current.terms + (t,), rows.duty, rows.temperature_c, current)
            for t in pool}
    scores = {n: current.bic - fit.bic for n, fit in fits.items()}
    by_name = {t.name: t for t in pool}
    for n, fit in fits.items():
        state["candidates"].append({"name": n, "score": scores[n], "round": rnd, "in_catalogue": by_name[n].in_catalogue,
                                    "parameters": _param_json(fit.parameters().get(n, {}))})
    ranked = sorted(scores, key=scores.get, reverse=True)
    while ranked:
        top, rest = ranked[0], ranked[1:]
        runner_up = max((scores[n] for n in rest), default=0.0)
        if scores[top] < NAME_DELTA_BIC or scores[top] - max(runner_up, 0.0) < RUNNER_UP_DELTA_BIC:
            return None
        scale = _scale_rel_std(fits[top])
        if scale > MAX_SCALE_REL_STD and not _determined_without_redundant(rows, w, fits[top]):
            state["suspects"].append({"name": top, "round": rnd, "score": scores[top], "scale_rel_std": scale})
            ranked = rest  # its size is not determined: it trades with the baseline, it is not a finding
            continue
        proof = _inner_proof(rows, w, current.terms, by_name[top], inner)
        if proof is not None and proof["with"] >= proof["without"]:
            swap = _in_place(rows, w, current, by_name[top])
            if swap is not None:
                gone, fit = swap
                state["chosen"].remove(gone)
                state["chosen"].append(top)
                state["dropped"] = state.get("dropped", []) + [{"name": gone, "replaced_by": top,
                                                                 "delta_bic": fit.bic - current.bic}]
                seq.append(fit)
                return top
            state["suspects"].append({"name": top, "round": rnd, "score": scores[top], "inner_held_out_rms_log10": proof})
            ranked = rest  # refused this round; tried again beside the next term taken
            continue
        state["chosen"].append(top)
        seq.append(fits[top])
        return top
    return None


def _in_place(rows: Rows, w: np.ndarray, current: TermFit, term: Term) -> tuple[str, TermFit] | None:
    """A generic term that fails on top of an earlier generic one may be the better description in its
    place: a Steinmetz law's table took the rate series first, by the tiers' order (held out 0.097 log10
    where the law itself gives 0.009).  The model with ``term`` instead of it is taken when decisively
    better (NAME_DELTA_BIC), its size determined and none of its exponents on a bound: a form whose
    exponent the data push to its bound does not describe them (N87's shapes: alpha 4.0, 0.39 log10 held
    out).  Not the inner extrapolation: between two look-alikes its window (50-90 kHz) ranks them by
    chance (the law 0.042, the series 0.036).  The earlier term's name and the swapped fit, or None."""
    if term.kind == "temperature":  # a factor on the whole energy, no rate term's stand-in
        return None
    lo, hi = term_bounds(term)
    for u in current.terms:
        if u.in_catalogue or u.kind == "temperature":
            continue
        kept = tuple(v for v in current.terms if v is not u) + (term,)
        fit = fit_terms(rows.f, rows.b, w, kept, rows.duty, rows.temperature_c)
        x = fit.x[fit.x.size - n_params(term):][1:]  # its exponents (the first is its scale)
        on_bound = np.any(np.isclose(x, lo[1:]) | np.isclose(x, hi[1:]))
        if current.bic - fit.bic >= NAME_DELTA_BIC and _scale_rel_std(fit) <= MAX_SCALE_REL_STD and not on_bound:
            return u.name, fit
    return None


def _reach_note(f_train: np.ndarray, f_held: np.ndarray, split: str) -> str:
    """A verdict's caveat where the held-out rows lie further above the calibration band than the band
    spans (a datasheet's 20 frequencies calibrated on 50-92 kHz, held out to 500 kHz: a Steinmetz law's
    growth then took the rate series, 1.40x, and either extrapolation is a guess); '' otherwise (the
    MagNet tables: 50-190 kHz, a factor of 3.8, held out 2.6x above it)."""
    top, bottom = float(f_train.max()), float(f_train.min())
    reach = float(f_held.max()) / top if f_held.size else 0.0
    if reach <= top / bottom:
        return ""
    return (f"; the calibration rows span {_hz(bottom)} to {_hz(top)} (a factor of {top / bottom:.3g}) and the "
            f"held-out rows reach {reach:.3g}x above them: how a rate term grows that far is not determined by "
            f"the band{_interleaved_hint(np.concatenate([f_train, f_held]), split)}")


def _interleaved_hint(f: np.ndarray, split: str) -> str:
    """Where the prescribed split is too narrow: the other split, when the table allows it."""
    if split != "low_third":
        return ""
    try:
        split_mask(f, "interleaved")
    except EstimationError:  # too few frequencies for it
        return ""
    return "; the interleaved split calibrates across the band"


def _hz(value: float) -> str:
    for scale, unit in ((1e9, "GHz"), (1e6, "MHz"), (1e3, "kHz")):
        if value >= scale:
            return f"{value / scale:.3g} {unit}"
    return f"{value:.3g} Hz"


def _determined_without_redundant(rows: Rows, w: np.ndarray, fit: TermFit) -> bool:
    """Whether the last term's size is determined once an earlier term it makes redundant is gone (the
    model without that term within NAME_DELTA_BIC, as :func:`_drop_redundant` drops it).  Why: beside a
    look-alike the two trade along a valley, and where the fit stops in it sets both sizes' errors (a free
    Steinmetz truth beside the rate series taken before it: 1.7 from one optimiser's path, below 0.5 from
    another)."""
    for t in fit.terms[:-1]:
        kept = tuple(u for u in fit.terms if u is not t)
        lean = fit_terms(rows.f, rows.b, w, kept, rows.duty, rows.temperature_c)
        if lean.bic - fit.bic < NAME_DELTA_BIC and _scale_rel_std(lean) <= MAX_SCALE_REL_STD:
            return True
    return False


def _scale_rel_std(fit: TermFit) -> float:
    """The relative standard error of the last term's energy at the reference point (100 kHz, 0.1 T, a
    sine; by the delta method from the fit's covariance), 0 for the temperature factor (no energy)."""
    t = fit.terms[-1]
    if t.kind == "temperature":
        return 0.0
    i = 3 + sum(n_params(u) for u in fit.terms[:-1])
    x = fit.x[i:i + n_params(t)]
    grad = np.zeros(x.size)
    if t.kind == "series":  # ln(k_1 + k_2) there: each order's share of the energy
        grad[[0, 2]] = np.exp(x[[0, 2]] - np.logaddexp(x[0], x[2]))
    else:
        grad[0] = 1.0  # ln k (the relaxation's and the free term's energy there; a fixed term's scale)
    cov = fit.cov[i:i + x.size, i:i + x.size]
    return float(math.sqrt(max(grad @ cov @ grad, 0.0)))


def _param_json(p: dict[str, tuple[float, float]]) -> dict[str, dict[str, float | None]]:
    """A parameter the rows do not determine has no standard error: ``"std": null``."""
    return {k: {"value": float(v), "std": float(s) if math.isfinite(s) else None} for k, (v, s) in p.items()}


CALIBRATE_ON = ("sine_triangle", "all_shapes")


def calibrate_split(f: np.ndarray, b: np.ndarray, w: np.ndarray, split: str = "low_third",
                    duty: np.ndarray | None = None, *, temperature_c: np.ndarray | None = None,
                    calibrate_on: str = "sine_triangle") -> tuple[np.ndarray, TermFit, TermFit, list[dict[str, Any]],
                                                                   list[str]]:
    """Calibration mask, the baseline's fit, the fit with the named terms, the scored candidates and
    the named terms' names (what :func:`diagnose_energy` and the figures share).  With ``duty`` only
    the sines and symmetric triangles of the split's frequencies are calibrated on (``calibrate_on``
    ``all_shapes``: every shape of those frequencies, where a relaxation term can be identified)."""
    train, seq, candidates, chosen, _, _ = select_on_split(Rows(f, b, duty, temperature_c), w, split, calibrate_on)
    return train, seq[0], seq[-1], candidates, chosen


#: The last few selections, by what they were computed from: a report's figures draw the models the
#: diagnosis selected a moment before, and a selection is seconds of fits (N87's report: 9 -> 5 s).
_SELECTIONS: dict[bytes, tuple[Any, ...]] = {}
_SELECTIONS_KEPT = 8


def _selection_key(rows: Rows, w: np.ndarray, split: str, calibrate_on: str) -> bytes:
    h = hashlib.blake2b(f"{split}|{calibrate_on}".encode(), digest_size=20)
    for a in (rows.f, rows.b, rows.duty, rows.temperature_c, rows.waveform, w):
        if a is None:
            h.update(b"none")
        else:
            a = np.ascontiguousarray(a, dtype=np.float64)
            h.update(repr(a.shape).encode())
            h.update(a.tobytes())
    return h.digest()


def select_on_split(rows: Rows, w: np.ndarray, split: str, calibrate_on: str
                    ) -> tuple[np.ndarray, list[TermFit], list[dict[str, Any]], list[str], list[dict[str, Any]],
                               dict[str, str]]:
    """The term selection on the split's calibration rows (``calibrate_on``: sine_triangle keeps only
    sines and symmetric triangles of those frequencies): (the calibration mask, the selected sequence,
    the candidates, the chosen terms, the suspects, the terms skipped), one place for every table
    kind (loss tables, the measured waveforms).  The same rows give the same selection, computed once
    (each caller gets its own copy)."""
    key = _selection_key(rows, w, split, calibrate_on)
    if key not in _SELECTIONS:
        if len(_SELECTIONS) >= _SELECTIONS_KEPT:
            del _SELECTIONS[next(iter(_SELECTIONS))]
        _SELECTIONS[key] = _select_on_split(rows, w, split, calibrate_on)
    return copy.deepcopy(_SELECTIONS[key])


def _select_on_split(rows: Rows, w: np.ndarray, split: str, calibrate_on: str) -> tuple[Any, ...]:
    if calibrate_on not in CALIBRATE_ON:
        raise EstimationError(f"calibrate_on {calibrate_on!r}: choose {' or '.join(CALIBRATE_ON)}")
    train = split_mask(rows.f, split)
    if rows.duty is not None:
        if calibrate_on == "sine_triangle":
            train &= calibration_shapes(rows.duty)
        if train.sum() < MIN_DECIDING_ROWS:
            raise EstimationError(f"split {split!r}: {int(train.sum())} calibration rows at the calibration "
                                  f"frequencies; at least {MIN_DECIDING_ROWS} are needed" + (
                                      " (the baseline is calibrated on the sines and symmetric triangles, duty 0.5, 0, "
                                      "0.5, 0, of those frequencies: give the material's sine table beside its shapes)"
                                      if calibrate_on == "sine_triangle" else ""))
    # The fits' linear algebra is a few thousand SVDs of tall, thin Jacobians: a second BLAS thread
    # makes them no faster alone and, beside other work, spins for its share (a fit took 53 s instead
    # of 4 s in the parallel test run; docs/performance.md).
    with threadpool_limits(limits=1, user_api="blas"):
        seq, candidates, chosen, suspects, skipped = _select(rows.take(train), w[train], split)
    return train, seq, candidates, chosen, suspects, skipped


def diagnose_energy(f: np.ndarray, b: np.ndarray, w: np.ndarray, *, material: str = "",
                    split: str = "low_third", duty: np.ndarray | None = None,
                    temperature_c: np.ndarray | None = None, calibrate_on: str = "sine_triangle",
                    row_names: Sequence[str] | None = None) -> dict[str, Any]:
    """The whole diagnosis of one energy-per-cycle table (see the module docstring); JSON-ready.
    ``duty``: (rows, 4) MagNet duties (None: every row a sine); with it the result has ``shapes``.
    ``temperature_c``: per-row temperature (a temperature term is a candidate where it varies).
    ``row_names``: how the verdict names a row it leaves out (``file:line``; default its index)."""
    t0 = time.perf_counter()
    f, b, w = (np.asarray(a, dtype=np.float64) for a in (f, b, w))
    if not (f.size == b.size == w.size) or f.size < 12:
        raise EstimationError(f"{material or 'table'}: need >= 12 rows of equal length, got {f.size}, {b.size}, {w.size}")
    if not (np.all(np.isfinite(w)) and np.all(w > 0)):
        raise EstimationError(f"{material or 'table'}: energy per cycle must be finite and > 0 in every row")
    if duty is not None:
        duty = np.asarray(duty, dtype=np.float64)
        if duty.shape != (f.size, 4):
            raise EstimationError(f"{material or 'table'}: duty must be (rows, 4) = ({f.size}, 4), got {duty.shape}")
    if temperature_c is not None:
        temperature_c = np.asarray(temperature_c, dtype=np.float64)
        if temperature_c.shape != f.shape or not np.all(np.isfinite(temperature_c)):
            raise EstimationError(f"{material or 'table'}: temperature must be finite, one per row")
    # a gross error in a row (a value mistyped x100) had set the noise floor to 8x the scatter and hidden a
    # classical eddy current: such rows are left out of everything and named
    outliers, (f, b, w, duty, temperature_c) = screened(f, b, w, duty, temperature_c)
    if outliers.sum() > _most_outliers(outliers.size):
        raise EstimationError(f"{material or 'table'}: {int(outliers.sum())} of {outliers.size} rows lie more than a factor "
                              f"of {OUTLIER_FACTOR:g} off the smooth curve of their neighbours (first: "
                              f"{f'row {int(np.argmax(outliers))}' if row_names is None else row_names[int(np.argmax(outliers))]}): "
                              "not glitches but the table itself (a column in another unit?)")
    rows = Rows(f, b, duty, temperature_c)
    train, seq, candidates, chosen, suspects, skipped = select_on_split(rows, w, split, calibrate_on)
    base, final = seq[0], seq[-1]
    held = ~train
    noise = noise_floor(f, b, w, duty)
    y = np.log10(w)
    r_before = y - base.log_w(f, b) / LN10
    r_after = y - final.log_w(f, b, duty, temperature_c) / LN10
    model_floor = _rms(r_before[train])
    located = _locate(f, b, r_before, held, noise, model_floor)
    beyond = _beyond_catalogue(rows, w, train, final, suspects)
    before, after = _rms(r_before[held]), _rms(r_after[held])
    steps = []
    for fit in seq[1:]:
        r = y[held] - fit.log_w(f[held], b[held], None if duty is None else duty[held],
                                None if temperature_c is None else temperature_c[held]) / LN10
        steps.append({"terms": [t.name for t in fit.terms], "residual_after_log10": _rms(r),
                      "improvement": before / max(_rms(r), 1e-300)})
    shapes = None if duty is None else locate_shapes(duty, r_before, r_after, held, noise, _rms(r_after[train]))
    params = final.parameters()
    by_name = {t.name: t for t in LIBRARY}
    reported = [form(by_name[n], params[n]) for n in chosen]
    verdict = _verdict(chosen, reported, located, beyond, after, shapes, suspects, skipped)
    if chosen and after > before:
        verdict += (f"; the model with them predicts the held-out rows worse than the baseline ({before:.3f} -> "
                    f"{after:.3f} log10): what they describe holds where they were calibrated and does not carry "
                    "beyond it; weigh them with that")
    if not chosen and train.sum() < MIN_DECIDING_ROWS:
        verdict += (f"; only {int(train.sum())} calibration rows: too few to decide a rate term (at least "
                    f"{MIN_DECIDING_ROWS}{_interleaved_hint(f, split)})")
    verdict += _reach_note(f[train], f[held], split)
    span = float(b.max() / b.min())
    if span < 2.0:  # a datasheet's curve at one flux density, or a narrow band of them
        verdict += ((f"; every row at one flux density ({1e3 * b.min():.3g} mT)" if span < 1.0001 else
                     f"; the flux densities span a factor of {span:.2g} only ({1e3 * b.min():.3g}-{1e3 * b.max():.3g} mT)") + ": "
                    "the loss's B dependence (beta, each term's delta) is not measured, and a size quoted at 0.1 T "
                    "is extrapolated there")
    keys = np.column_stack([f, b, w] + ([] if duty is None else [duty]))
    repeated = int(f.size - np.unique(keys, axis=0).shape[0])
    if outliers.any():
        first = ", ".join(str(i) if row_names is None else row_names[i] for i in np.flatnonzero(outliers)[:5])
        verdict += (f"; {int(outliers.sum())} {'row' if outliers.sum() == 1 else 'rows'} left out, each more than a factor of {OUTLIER_FACTOR:g} off the "
                    f"smooth curve of its neighbours (a mistyped value?): {'rows ' if row_names is None else ''}{first}"
                    f"{', ...' if outliers.sum() > 5 else ''}")
    if repeated:  # a table appended twice counts its evidence twice (N87's sines doubled took a third term)
        verdict += (f"; {repeated} rows repeat another exactly (a table appended twice?): each is counted, which "
                    "overstates the evidence")
    return {
        "material": material, "split": split, "calibrate_on": calibrate_on,
        "effect": next((n for n in chosen if by_name[n].in_catalogue), None),
        "effects": chosen, "not_in_catalogue": [n for n in chosen if not by_name[n].in_catalogue],
        "reported": reported, "steps": steps, "suspects": suspects, "not_identifiable": skipped,
        "candidates": candidates,
        "parameters": {k: _param_json(v) for k, v in params.items() if k in chosen},
        "recalibrated": {f"static_hysteresis.{k}": {**v, "prior": None}
                         for k, v in _param_json(params["static_hysteresis"]).items()},
        "located": located,
        "residual_before": before / noise, "residual_after": after / noise,
        "residual_before_log10": before, "residual_after_log10": after,
        "improvement": before / after if after > 0 else None,
        "noise_floor": {"log10_W": noise},
        "beyond_catalogue": beyond, "verdict": verdict,
        "rows": {"calibration": int(train.sum()), "held_out": int(held.sum()),
                 "calibration_max_Hz": float(f[train].max())},
        **({} if shapes is None else {"shapes": shapes}),
        "repeated_rows": repeated,
        "outlier_rows": np.flatnonzero(outliers).tolist(),  # indices into the rows given, left out of everything
        **({} if row_names is None else {"outlier_lines": [row_names[i] for i in np.flatnonzero(outliers)]}),
        "seconds": time.perf_counter() - t0,
    }


def _beyond_catalogue(rows: Rows, w: np.ndarray, train: np.ndarray, named: TermFit,
                      suspects: list[dict[str, Any]]) -> dict[str, Any]:
    """The free-exponent rate term alone in place of the selected ones: does it fit the calibration
    points decisively better (``needed``) than what was selected?  It is itself a candidate of the
    selection: ``needed`` is then true only when the selection refused it (see ``suspects``)."""
    rt = rows.take(train)
    fit = fit_terms(rt.f, rt.b, w[train], (STEINMETZ,), rt.duty, rt.temperature_c)
    r = np.log10(w) - fit.log_w(rows.f, rows.b, rows.duty, rows.temperature_c) / LN10
    p = fit.parameters()[STEINMETZ.name]
    gamma, delta = fit.x[-2], fit.x[-1]
    at_bound = bool(np.isclose(gamma, FREE_BOUNDS[0][0]) or np.isclose(gamma, FREE_BOUNDS[1][0])
                    or np.isclose(delta, FREE_BOUNDS[0][1]) or np.isclose(delta, FREE_BOUNDS[1][1]))
    refused = next((s for s in suspects if s["name"] == STEINMETZ.name and not s.get("dropped")), None)
    return {"name": STEINMETZ.name, "delta_bic": named.bic - fit.bic, "at_bound": at_bound,
            "needed": named.bic - fit.bic >= NAME_DELTA_BIC,
            "modelled": STEINMETZ.name in [t.name for t in named.terms], "refused": refused,
            **_param_json({"alpha": p["alpha"], "delta": p["delta"]}),
            "residual_held_out_log10": _rms(r[~train])}


def _verdict(chosen: list[str], reported: list[str], located: dict[str, Any], beyond: dict[str, Any],
             named_after: float, shapes: dict[str, Any] | None, suspects: list[dict[str, Any]],
             skipped: dict[str, str]) -> str:
    tr = located["trend"]
    way = "grows with" if tr["slope_log_f"] >= 0 else "falls with"
    where = (f"held-out energy per cycle {way} frequency beyond the rate-independent baseline as f^"
             f"{tr['slope_log_f']:.2f} +- {tr['slope_log_f_std']:.2f} (max |z| {located['max_abs_z']:.1f})")
    out = (f"{where}; modelled: {'; '.join(reported)}" if chosen
           else f"{where}; nothing significant named at the calibration frequencies")
    for s in suspects:
        if s.get("replaced_by"):
            out += (f"; {s['name']} replaced by {s['replaced_by']}: decisively better in its place (delta BIC "
                    f"{s['delta_bic']:.1f})")
            continue
        if s.get("dropped"):
            out += f"; {s['name']} dropped: redundant beside the generic term taken after it (delta BIC {s['delta_bic']:.1f})"
            continue
        if "scale_rel_std" in s:
            out += (f"; {s['name']} fits the calibration points decisively (delta BIC {s['score']:.0f}) but its size "
                    f"is not determined (relative standard error {s['scale_rel_std']:.2g}: it trades with the baseline): "
                    "refused as a suspect")
            continue
        p = s["inner_held_out_rms_log10"]
        out += (f"; {s['name']} fits the calibration points decisively (delta BIC {s['score']:.0f}) but, fitted on "
                f"their lower part, predicts their upper part worse ({p['without']:.3f} -> {p['with']:.3f} log10): "
                "refused as a suspect (it does not extrapolate)")
    if beyond["needed"] and not beyond["modelled"]:
        a = beyond["alpha"]
        spread = "not determined" if a["std"] is None else f"+- {a['std']:.2f}"
        out += (f"; alone, the free rate term (alpha = {a['value']:.2f} {spread}"
                f"{', on its bound' if beyond['at_bound'] else ''}) would give {beyond['residual_held_out_log10']:.3f} "
                f"log10 held out, against {named_after:.3f} with the model selected")
    if shapes is not None:
        out += "; held out per shape group, rms log10 before -> after: " + ", ".join(
            f"{g} {v['residual_before_log10']:.3f} -> {v['residual_after_log10']:.3f}"
            for g, v in shapes["groups"].items())
        worst = ", ".join("(" + ", ".join(f"{x:g}" for x in d) + ")" for d in shapes["missed_most"])
        out += f"; missed most: duty {worst}"
        tr, fl = shapes["between_ramps_trend"], shapes["flat_trend"]
        if tr is not None:
            out += (f"; the residual after changes by {tr['slope_log10_per_share']:+.3f} +- {tr['slope_std']:.3f} "
                    "log10 per unit of the period between the ramps")
            if fl is not None:
                out += (f" ({fl['slope_log10_per_share']:+.3f} +- {fl['slope_std']:.3f} where B is flat there, "
                        "duty_1 == duty_3)")
            if "flat_segment_relaxation" in skipped:
                out += " (relaxation not identifiable: " + skipped["flat_segment_relaxation"] + ")"
    return out


TableArg = str | Path | LossTable


def _read(t: TableArg) -> LossTable:
    return t if isinstance(t, LossTable) else read_material_table(t)


def loss_table_groups(tables: Sequence[TableArg]) -> list[list[LossTable]]:
    """Read every table (all checked before any diagnosis) and group them: the core-loss tables of a
    material of which one holds triangular/trapezoidal rows go together (sine tables first), in the
    order the material first appears; every other table is its own group."""
    read = [_read(t) for t in tables]
    seen: dict[Path, Path] = {}
    for t in read:  # one file twice would count its evidence twice
        if t.path.resolve() in seen:
            raise RecordingError(f"{t.path}: given twice (as {seen[t.path.resolve()]} too); give each table once")
        seen[t.path.resolve()] = t.path
    shaped = {_conditions(t) for t in read if t.kind == "core_loss" and np.any(t.duty[:, 0] != -1)}
    groups: list[list[LossTable]] = []
    by_material: dict[tuple[str, str, str], list[LossTable]] = {}
    for t in read:
        key = _conditions(t)
        if t.kind == "core_loss" and key in shaped:
            if key not in by_material:
                by_material[key] = []
                groups.append(by_material[key])
            by_material[key].append(t)
        else:
            groups.append([t])
    for g in groups:
        g.sort(key=lambda t: bool(np.any(t.duty[:, 0] != -1)))
    return groups


def _conditions(t: LossTable) -> tuple[str, str, str]:
    """What tables diagnosed together must share: the material, and the core and temperature it was
    measured on (a ferrite's loss moves by a factor of two between 25 and 100 degC)."""
    return t.material, _said(t, "temperature_C"), _said(t, "core_shape")


def _said(t: LossTable, key: str) -> str:
    """A sidecar's value as compared: 25 and 25.0 degC are one temperature."""
    v = t.metadata.get(key)
    return repr(float(v)) if isinstance(v, (int, float)) and not isinstance(v, bool) else repr(v)


def energy_table(tables: list[LossTable]) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]:
    """f, B, W and the duties (None when every row is a sine) of tables of one material, measured on
    one core at one temperature."""
    first = tables[0]
    for t in tables[1:]:
        if t.material != first.material or t.kind != "core_loss" or first.kind != "core_loss":
            raise RecordingError(f"{t.path}: {t.kind} table of {t.material!r} read with {first.path} ({first.kind} "
                                 f"of {first.material!r}); tables are diagnosed together only as core-loss tables "
                                 "of one material")
        for key in ("temperature_C", "core_shape"):
            if _said(t, key) != _said(first, key):
                raise RecordingError(f"{t.path.with_suffix('.json')}: {key} {t.metadata.get(key)!r}, but "
                                     f"{first.path.with_suffix('.json')} says {first.metadata.get(key)!r}; tables are "
                                     f"diagnosed together only when measured alike")
    for t in tables:  # the reader takes a loss of 0; the diagnosis works on its logarithm
        zero = t.columns["loss_W_per_m3"] <= 0 if t.kind == "core_loss" else np.zeros(len(t), bool)
        if zero.any():
            raise RecordingError(f"{t.path}:{int(np.argmax(zero)) + 2}: column loss_W_per_m3: a loss of 0; the "
                                 "diagnosis compares log(energy per cycle) and needs a loss > 0 in every row")
    ws = []
    for t in tables:  # a loss of 1e-320 W/m^3, a permeability of 1e300: a row's energy that is no number
        with np.errstate(all="ignore"):
            w_t = energy_per_cycle(t, shapes=True)
        bad = ~(np.isfinite(w_t) & (w_t > 0))
        if bad.any():
            r = int(np.argmax(bad))
            raise RecordingError(f"{t.path}:{r + 2}: the row's energy per cycle is {float(w_t[r])!r} J/m^3; the "
                                 "diagnosis compares log(energy per cycle) and needs a finite one > 0 in every row")
        ws.append(w_t)
    f = np.concatenate([t.frequency_hz for t in tables])
    b = np.concatenate([t.flux_density_t for t in tables])
    w = np.concatenate(ws)
    duty = np.concatenate([t.duty for t in tables])
    return f, b, w, (None if np.all(duty[:, 0] == -1) else duty)


def _diagnose_group(tables: list[LossTable], split: str, calibrate_on: str = "sine_triangle") -> dict[str, Any]:
    f, b, w, duty = energy_table(tables)
    try:
        out = diagnose_energy(f, b, w, material=tables[0].material, split=split, duty=duty, calibrate_on=calibrate_on,
                              row_names=[f"{t.path}:{i + 2}" for t in tables for i in range(len(t))])
    except EstimationError as err:  # what the table cannot give, said with its name
        raise EstimationError(f"{tables[0].path}: {err}") from None
    out["path"], out["kind"] = str(tables[0].path), tables[0].kind
    if len(tables) > 1:
        out["paths"] = [str(t.path) for t in tables]
    return out


_HEADLINE = ("split", "calibrate_on", "effects", "reported", "suspects", "residual_before_log10",
             "residual_after_log10", "improvement", "beyond_catalogue")


def _headline(r: dict[str, Any]) -> dict[str, Any]:
    out = {k: r[k] for k in _HEADLINE}
    if "shapes" in r:
        out["shape_groups"] = r["shapes"]["groups"]
    return out


def diagnose_loss_table(tables: TableArg | Sequence[TableArg], split: str = "low_third", *,
                        all_shapes: bool = False) -> dict[str, Any]:
    """Read a material table (core loss or complex permeability), or several core-loss tables of one
    material (a sine table with MagNet's triangles/trapezoids of the same material), and diagnose them
    together; the result also carries the other split's headline figures and, with triangles and
    trapezoids (and ``all_shapes``), those of a calibration on every shape of the calibration
    frequencies (``all_shapes``: where flat segments are calibrated on, so a relaxation term can be
    identified; still held out at every other frequency).  ``path`` is the first table's (a sine
    table's when there is one), ``paths`` all of them when several."""
    group = [_read(t) for t in ([tables] if isinstance(tables, (str, Path, LossTable)) else tables)]
    if not group:
        raise EstimationError("no loss table given")
    group.sort(key=lambda t: bool(np.any(t.duty[:, 0] != -1)))
    out = _diagnose_group(group, split)
    other = "interleaved" if split == "low_third" else "low_third"
    try:
        out["other_split"] = _headline(_diagnose_group(group, other))
    except EstimationError as err:  # a table with few frequencies may allow one split only
        out["other_split"] = {"split": other, "refused": str(err)}
    if all_shapes and "shapes" in out:
        out["all_shapes"] = _headline(_diagnose_group(group, split, "all_shapes"))
    return out


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m hystbench.analysis.diagnosis.loss_separation [--all-shapes] TABLE.csv ...``: one line
    per table (a material's sine and shapes tables together, :func:`loss_table_groups`), split and
    calibration set (``all_shapes`` only with triangles/trapezoids and ``--all-shapes``: minutes a table), then for the shape groups their held-out errors and
    the shapes missed most, and the terms refused as suspects."""
    paths = list(sys.argv[1:] if argv is None else argv)
    all_shapes = "--all-shapes" in paths  # also calibrate on every shape of the calibration frequencies (slow)
    paths = [p for p in paths if p != "--all-shapes"]
    if not paths:
        print("usage: python -m hystbench.analysis.diagnosis.loss_separation [--all-shapes] TABLE.csv ...", file=sys.stderr)
        return 2
    print(f"{'table':28s} {'split':11s} {'calibrated on':13s} {'rows c/h':>11s} {'before':>7s} {'after':>7s} "
          f"{'ratio':>6s} {'f-slope':>12s} {'modelled':45s} {'s':>5s}")
    for group in loss_table_groups(paths):
        name = "+".join(t.path.stem for t in group)
        shaped = any(np.any(t.duty[:, 0] != -1) for t in group)
        runs = [("low_third", "sine_triangle"), ("interleaved", "sine_triangle")]
        for split, on in runs + ([("low_third", "all_shapes")] if shaped and all_shapes else []):
            r = _diagnose_group(group, split, on)
            tr = r["located"]["trend"]
            print(f"{name:28s} {split:11s} {on:13s} {r['rows']['calibration']:5d}/{r['rows']['held_out']:<5d} "
                  f"{r['residual_before_log10']:7.3f} {r['residual_after_log10']:7.3f} {r['improvement']:6.2f} "
                  f"{tr['slope_log_f']:5.2f}+-{tr['slope_log_f_std']:.2f} {'+'.join(r['effects']) or 'none':45s} "
                  f"{r['seconds']:5.2f}")
            for g, v in r.get("shapes", {}).get("groups", {}).items():
                print(f"{'':54s} {g:>11s} {v['residual_before_log10']:7.3f} {v['residual_after_log10']:7.3f} "
                      f"{v['improvement']:6.2f}  ({v['held_out']} held out; {v['residual_before']:.1f} -> "
                      f"{v['residual_after']:.1f} noise floors)")
            for rep in r["reported"]:
                print(f"{'':54s} {rep}")
            for sus in r["suspects"]:
                if sus.get("replaced_by"):
                    print(f"{'':54s} replaced {sus['name']} by {sus['replaced_by']} (delta BIC {sus['delta_bic']:.1f})")
                    continue
                if sus.get("dropped"):
                    print(f"{'':54s} dropped {sus['name']} (redundant, delta BIC {sus['delta_bic']:.1f})")
                    continue
                if "scale_rel_std" in sus:
                    print(f"{'':54s} suspect {sus['name']} (delta BIC {sus['score']:.0f}; its size undetermined, "
                          f"relative std {sus['scale_rel_std']:.2g})")
                    continue
                p = sus["inner_held_out_rms_log10"]
                print(f"{'':54s} suspect {sus['name']} (delta BIC {sus['score']:.0f}; inner held out "
                      f"{p['without']:.3f} -> {p['with']:.3f})")
    return 0


if __name__ == "__main__":
    raise SystemExit(script_status(main))
