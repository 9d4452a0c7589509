"""Weighted least squares over the bench day's features, and the score that names an effect.

Every number's variance is its standard error squared plus a model-error floor: a share of the
channel's largest harmonic in that recording (``MODEL_ERROR_FLOOR``, per view).  The floor is what
keeps a baseline that is merely imperfect (a real iron is never the preset's) from raising alarms;
it was set on the null cases of the concealed suite, foreign benches included
(``python -m benchmarks diagnose``).  Calibration parameters carry their priors as extra rows.

The score of a candidate is the Bayesian information criterion's difference with the baseline,
``chi2_base - chi2_cand - p ln n``: it charges each parameter ln n, so an effect is only worth
naming when it explains far more than its parameters could explain in noise.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any, Callable, Mapping, Sequence

import numpy as np
from scipy.optimize import lsq_linear

__all__ = ["MODEL_ERROR_FLOOR", "DC_FLOOR", "FLOOR_FACTOR_RANGE", "floor_scales", "Column", "Solution", "Problem", "solve", "variance"]

#: Relative model-error floor per view (share of the channel's largest harmonic in the recording).
MODEL_ERROR_FLOOR: Mapping[str, float] = {"current vs command": 2e-5, "flux vs current": 3e-4,
                                          "force vs current": 3e-4, "lines": 0.0}


@dataclass(frozen=True)
class Column:
    """One linear parameter: how the model vector moves per unit, its prior width (None: no prior,
    a candidate's parameter) and its bounds."""

    name: str
    values: np.ndarray
    prior: float | None = None
    lower: float = -math.inf
    upper: float = math.inf


@dataclass(frozen=True)
class Solution:
    beta: np.ndarray
    cov: np.ndarray
    chi2: float  # data rows only (priors excluded)
    chi2_prior: float
    names: tuple[str, ...]
    fitted: np.ndarray  # the model's change at beta (data rows)

    def value(self, name: str) -> tuple[float, float]:
        i = self.names.index(name)
        return float(self.beta[i]), float(math.sqrt(max(self.cov[i, i], 0.0)))


#: Relative model-error floor of a channel's DC (share of its largest harmonic or of the DC itself):
#: a force law off by a few per mille moves a magnet's 170 N bias by tenths of a newton, more than any
#: harmonic's error; a high-pass that loses the whole DC or a drift of 0.1 N along the day stay far above.
DC_FLOOR = 1e-2


#: The floor's factor per part of the bench day (view x rig) is fitted to the calibrated baseline's
#: residual, within these bounds: a baseline that is the bench (our nominal rigs) is judged at a tenth
#: of the fixed floor; one whose iron or instrument differ, at what it misses by.
FLOOR_FACTOR_RANGE = (0.1, 100.0)


#: The median of a chi-square with one degree of freedom.
FLOOR_MEDIAN = 0.454936


def variance(se: np.ndarray, scale: np.ndarray, views: np.ndarray, harmonic: np.ndarray,
             factor: np.ndarray | float = 1.0) -> np.ndarray:
    """Each number's variance: its standard error squared plus the model-error floor (times ``factor``)."""
    eps = np.where(harmonic == 0, DC_FLOOR, np.array([MODEL_ERROR_FLOOR[v] for v in views]))
    return se ** 2 + (factor * eps * scale) ** 2


def floor_scales(residual: np.ndarray, layout: Any, data: Sequence[Any], ok: np.ndarray) -> np.ndarray:
    """Per harmonic row, the factor on the model-error floor of its part of the bench day (its view on
    its rig): the one that makes the calibrated baseline's standardised residuals there as spread as
    noise (bisection in log), within FLOOR_FACTOR_RANGE.  A part the baseline fits to its noise keeps the
    lowest floor.  The spread is measured by the median of the squared residuals (a chi-square with one
    degree of freedom has median FLOOR_MEDIAN), not their mean: the residual holds what the baseline
    leaves out, and an effect that acts on a few numbers (a frame mode near two of the voice coil's
    points, a high-pass at the lowest frequencies) must not raise the floor that would reveal it."""
    views = layout.view()
    rigs = np.array([data[r].rig for r in layout.record])
    eps = np.where(layout.harmonic == 0, DC_FLOOR, np.array([MODEL_ERROR_FLOOR[v] for v in views])) * layout.scale
    r = residual[:layout.size]
    out = np.ones(layout.size)
    lo_f, hi_f = FLOOR_FACTOR_RANGE
    for key in set(zip(views, rigs)):
        sel = (views == key[0]) & (rigs == key[1]) & ok
        if not sel.any():
            continue
        r2, se2, e2 = r[sel] ** 2, layout.se[sel] ** 2, eps[sel] ** 2

        def reduced(f: float) -> float:
            return float(np.median(r2 / (se2 + f * f * e2))) / FLOOR_MEDIAN

        lo, hi = math.log(lo_f), math.log(hi_f)
        if reduced(lo_f) <= 1.0:
            f = lo_f
        elif reduced(hi_f) >= 1.0:
            f = hi_f
        else:
            for _ in range(40):
                mid = 0.5 * (lo + hi)
                lo, hi = (mid, hi) if reduced(math.exp(mid)) > 1.0 else (lo, mid)
            f = math.exp(hi)
        out[(views == key[0]) & (rigs == key[1])] = f
    return out


#: A column whose part outside the span of the columns before it is this small (the columns scaled to
#: unit norm) is taken as inside it: rounding makes an exact dependence about 1e-15.
DEPENDENT_TOLERANCE = 1e-10


def solve(residual: np.ndarray, sigma: np.ndarray, columns: Sequence[Column], rows: np.ndarray | None = None) -> Solution:
    """Fit ``residual`` (data minus model) with ``columns`` on ``rows`` (all when None): bounded
    weighted least squares with each calibration column's prior as a pseudo-observation."""
    sel = np.arange(residual.size) if rows is None else np.asarray(rows)
    sel = sel[np.isfinite(residual[sel])]  # a model the simulator could not compute there: those rows say nothing
    w = 1.0 / sigma[sel]
    b = residual[sel] * w
    names = tuple(c.name for c in columns)
    if not columns:
        return Solution(np.zeros(0), np.zeros((0, 0)), float(b @ b), 0.0, names, np.zeros(residual.size))
    J = np.column_stack([c.values[sel] for c in columns]) * w[:, None]
    # A column the simulator could not compute on these rows (a replay that diverged: a recording
    # whose sidecar names another rig) is fitted without, its coefficient 0, as a dependent one is
    finite = np.all(np.isfinite(J), axis=0)
    J[:, ~finite] = 0.0
    norms = np.sqrt(np.sum(J ** 2, axis=0))
    norms = np.where(norms > 0, norms, 1.0)
    prior_rows = [(i, c.prior) for i, c in enumerate(columns) if c.prior is not None]
    P = np.zeros((len(prior_rows), len(columns)))
    for r, (i, width) in enumerate(prior_rows):
        P[r, i] = 1.0 / width
    A = np.vstack([J, P]) / norms
    y = np.concatenate([b, np.zeros(len(prior_rows))])
    lower = np.array([c.lower for c in columns]) * norms
    upper = np.array([c.upper for c in columns]) * norms
    bounded = np.isfinite(lower) | np.isfinite(upper)
    # ||A x - y||^2 = ||R x - Q'y||^2 + const (A = QR): the bounded solver's many inner least-squares
    # solves then work on an n x n triangle instead of thousands of rows, with the same minimiser
    Q, R = np.linalg.qr(A)
    # A column in the span of those before it (a refused suspect's generic term beside its own columns)
    # adds nothing to the fit and makes R singular: the solver's first least squares keeps singular
    # values down to machine precision and lost 15 of chi2 to rounding on such a fit.  Fitted without it
    # (its coefficient 0), when it is free; the span, and so the fit, is the same.
    keep = ((np.abs(np.diag(R)) > DEPENDENT_TOLERANCE) | bounded) & finite
    if not keep.all():
        Q, R = np.linalg.qr(A[:, keep])
    x = np.zeros(len(columns))
    if keep.any():
        x[keep] = lsq_linear(R, Q.T @ y, bounds=(lower[keep], upper[keep]),
                             method="bvls" if bounded.any() else "trf", lsmr_tol="auto").x
    beta = x / norms
    resid = b - J @ beta
    prior_term = P @ beta
    info = A.T @ A
    try:
        cov = np.linalg.pinv(info) / np.outer(norms, norms)
    except np.linalg.LinAlgError:  # LAPACK's SVD gave up (a finite, ill-conditioned 174 x 174 of a
        # recording labelled with another rig): the symmetric eigensolver, which the matrix allows
        cov = np.linalg.pinv(info, hermitian=True) / np.outer(norms, norms)
    full = np.column_stack([c.values for c, ok in zip(columns, finite) if ok]) @ beta[finite] if finite.any() \
        else np.zeros(residual.size)
    return Solution(beta, cov, float(resid @ resid), float(prior_term @ prior_term), names, full)


@dataclass(frozen=True)
class Problem:
    """One diagnosis's fit: the data vector, each number's sigma (standard error and floor), the rows
    that count, and the model (the replay's features for knob coordinates and extra effects)."""

    d: np.ndarray
    sigma: np.ndarray
    rows: np.ndarray
    #: the model vector for a list of (knobs, effects): several simulations at once
    model_many: Callable[[Sequence[tuple[Any, Any]]], list[np.ndarray]]
    layout: Any  # vector.Layout of the harmonic rows (the line rows follow them)
    noise: np.ndarray  # each number's standard error alone (no model-error floor): the unit of a residual
    line_records: np.ndarray  # the record of each line row

    def model(self, knobs: Mapping[str, float] | None = None,
              effects: Mapping[str, Mapping[str, Any]] | None = None) -> np.ndarray:
        return self.model_many([(knobs, effects)])[0]

    def solve(self, m: np.ndarray, columns: Sequence[Column], rows: np.ndarray | None = None) -> Solution:
        """The fit of the data minus model ``m`` with ``columns`` on ``rows`` (all that count when None)."""
        return solve(self.d - m, self.sigma, columns, self.rows if rows is None else rows)

    def with_effects(self, effects: Mapping[str, Mapping[str, Any]]) -> Problem:
        """The same fit with ``effects`` in the model's baseline (explicit effects still override them)."""
        base = self.model_many
        return dataclasses.replace(self, model_many=lambda requests: base(
            [(knobs, {**effects, **(extra or {})}) for knobs, extra in requests]))
