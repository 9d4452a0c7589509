"""Weighted least squares over the bench day's features, and the score that names an effect.

Every number's variance is its standard error squared plus a model-error floor: a share of the
channel's largest harmonic in that recording (``MODEL_ERROR_FLOOR``, per view).  The floor is what
keeps a baseline that is merely imperfect (a real iron is never the preset's) from raising alarms;
it was set on the null cases of the concealed suite, foreign benches included
(``hystbench bench diagnose``).  Calibration parameters carry their priors as extra rows.

The score of a candidate is the Bayesian information criterion's difference with the baseline,
``chi2_base - chi2_cand - p ln n``: it charges each parameter ln n, so an effect is only worth
naming when it explains far more than its parameters could explain in noise.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Mapping, Sequence

import numpy as np
from scipy.optimize import lsq_linear

__all__ = ["MODEL_ERROR_FLOOR", "Column", "Solution", "solve", "variance"]

#: Relative model-error floor per view (share of the channel's largest harmonic in the recording).
MODEL_ERROR_FLOOR: Mapping[str, float] = {"current vs command": 2e-5, "flux vs current": 3e-4,
                                          "force vs current": 3e-4, "lines": 0.0}


@dataclass(frozen=True)
class Column:
    """One linear parameter: how the model vector moves per unit, its prior width (None: no prior,
    a candidate's parameter) and its lower bound."""

    name: str
    values: np.ndarray
    prior: float | None = None
    lower: float = -math.inf


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


def variance(se: np.ndarray, scale: np.ndarray, views: np.ndarray) -> np.ndarray:
    eps = np.array([MODEL_ERROR_FLOOR[v] for v in views])
    return se ** 2 + (eps * scale) ** 2


def solve(residual: np.ndarray, sigma: np.ndarray, columns: Sequence[Column], rows: np.ndarray | None = None) -> Solution:
    """Fit ``residual`` (data minus model) with ``columns`` on ``rows`` (all when None): bounded
    weighted least squares with each calibration column's prior as a pseudo-observation."""
    sel = np.arange(residual.size) if rows is None else np.asarray(rows)
    w = 1.0 / sigma[sel]
    b = residual[sel] * w
    names = tuple(c.name for c in columns)
    if not columns:
        return Solution(np.zeros(0), np.zeros((0, 0)), float(b @ b), 0.0, names, np.zeros(residual.size))
    J = np.column_stack([c.values[sel] for c in columns]) * w[:, None]
    norms = np.sqrt(np.sum(J ** 2, axis=0))
    norms = np.where(norms > 0, norms, 1.0)
    prior_rows = [(i, c.prior) for i, c in enumerate(columns) if c.prior is not None]
    P = np.zeros((len(prior_rows), len(columns)))
    for r, (i, width) in enumerate(prior_rows):
        P[r, i] = 1.0 / width
    A = np.vstack([J, P]) / norms
    y = np.concatenate([b, np.zeros(len(prior_rows))])
    lower = np.array([c.lower for c in columns]) * norms
    res = lsq_linear(A, y, bounds=(lower, np.full(len(columns), np.inf)), method="bvls" if np.isfinite(lower).any() else "trf",
                     lsmr_tol="auto")
    beta = res.x / norms
    resid = b - J @ beta
    prior_term = P @ beta
    info = A.T @ A
    cov = np.linalg.pinv(info) / np.outer(norms, norms)
    full = np.column_stack([c.values for c in columns]) @ beta
    return Solution(beta, cov, float(resid @ resid), float(prior_term @ prior_term), names, full)
