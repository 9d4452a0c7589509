"""Least squares with the uncertainties every identification here reports.

One way for the linear fits (law, flux map, describing function, Rayleigh loops, the Preisach fit's
linear terms) and for the covariance of a nonlinear ``scipy.optimize.least_squares`` solution.
The standard errors are scaled by the fit's own residual variance (reduced chi^2), so they include
the model's misfit, not only the noise.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["LinearFit", "linear_fit", "scaled_lstsq", "solution_covariance"]


def scaled_lstsq(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """argmin |a x - b| with the columns scaled to one (their units differ by decades)."""
    scale = np.max(np.abs(a), axis=0)
    scale[scale == 0] = 1.0
    return np.linalg.lstsq(a / scale, b, rcond=None)[0] / scale


@dataclass(frozen=True)
class LinearFit:
    """Coefficients, their covariance and the residual b - a coef."""

    coef: np.ndarray
    cov: np.ndarray
    resid: np.ndarray

    @property
    def se(self) -> np.ndarray:
        return np.sqrt(np.maximum(np.diag(self.cov), 0.0))


def linear_fit(a: np.ndarray, b: np.ndarray) -> LinearFit:
    """:func:`scaled_lstsq` with the covariance (a'a)^-1 times the residual variance."""
    coef = scaled_lstsq(a, b)
    resid = b - a @ coef
    dof = max(b.size - coef.size, 1)
    return LinearFit(coef, np.linalg.pinv(a.T @ a) * float(resid @ resid) / dof, resid)


def solution_covariance(jac: np.ndarray, resid: np.ndarray, extra_parameters: int = 0) -> np.ndarray:
    """Covariance of a nonlinear least-squares solution from its Jacobian and residual;
    ``extra_parameters`` counts those solved for inside the residual (variable projection)."""
    dof = max(resid.size - jac.shape[1] - extra_parameters, 1)
    return np.linalg.pinv(jac.T @ jac) * float(resid @ resid) / dof
