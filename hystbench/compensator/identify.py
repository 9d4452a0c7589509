"""Identification of the hysteresis-eddy model (``hysteresis_eddy``) from a sweep of operating points.

1. Flux to current.  The gap force is quadratic in the gap flux, and the sense coil's flux is
   proportional to it up to the integrator's unknown DC, so per recording
   F_meas = H_instr{p2 phi^2 + p1_r phi + p0_r} with p2 shared (linear least squares, the
   instrument's response applied to the flux terms, so its gain and phase never enter the fit).
   With the ideal-iron MEC law F = k0 + k1 j + k2 j^2 this gives j = kappa phi + c_r:
   kappa = sqrt(p2 / k2), c_r = (p1_r / kappa - k1) / (2 k2), and the law's fitted k0.
2. The iron's share of the current, d = i - j, per recording.
3. The Preisach and eddy parameters by nonlinear least squares on d (see ``hysteresis_eddy``),
   from two starting points derived from the loops' widths (no material data is read).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np
from scipy.optimize import least_squares

from ..errors import ConfigError
from ..physics.hysteresis import PreisachHysteresis
from .data import PeriodData
from .errors import CompensatorError
from .hysteresis_eddy import (FIT_TABLES, HysteresisEddyModel, IronScaling, coercive_guess, iron_drop,
                              material_dict, preisach_params)
from .periodic import apply_response, derivative, resample
from .static import StaticLaw

__all__ = ["FluxCalibration", "calibrate_flux", "fit_hysteresis_eddy", "FIT_POINTS"]

FIT_POINTS = 400  # samples per period in the fit (the loops are smooth; 1000 costs 2.5x)
_KINDS = ("gauss", "lorentz")
#: Starting widths of the switching-field distributions, relative to the coercive guess.
START_SPREADS = (0.12, 0.3)
Response = Callable[[np.ndarray], np.ndarray]


@dataclass(frozen=True)
class FluxCalibration:
    """j = kappa * phi + offset_r for each recording, and the static law it implies."""

    kappa_a_per_wb: float
    offsets_a: tuple[float, ...]
    law: StaticLaw
    p2_spread: float  # relative scatter of per-recording p2 (0 for an exactly quadratic law)

    def as_dict(self) -> dict:
        return {"kappa_A_per_Wb": self.kappa_a_per_wb, "offsets_A": list(self.offsets_a),
                "k0_N": self.law.k0_n, "p2_relative_spread": self.p2_spread}


def calibrate_flux(points: Sequence[PeriodData], ideal: StaticLaw, response: Response) -> FluxCalibration:
    """Step 1 of the module docstring."""
    r = len(points)
    blocks, rhs, p2_each = [], [], []
    for n, p in enumerate(points):
        phi = np.asarray(p.flux_wb, float) - float(np.mean(p.flux_wb))
        sq = apply_response(phi * phi, p.frequency_hz, response)
        lin = apply_response(phi, p.frequency_hz, response)
        cols = np.zeros((p.n, 1 + 2 * r))
        cols[:, 0], cols[:, 1 + n], cols[:, 1 + r + n] = sq, lin, 1.0
        blocks.append(cols)
        rhs.append(np.asarray(p.force_n, float))
        own = np.linalg.lstsq(np.stack([sq, lin, np.ones(p.n)], axis=1), rhs[-1], rcond=None)[0]
        p2_each.append(own[0])
    coef = np.linalg.lstsq(np.vstack(blocks), np.concatenate(rhs), rcond=None)[0]
    p2, p1, p0 = coef[0], coef[1:1 + r], coef[1 + r:]
    k0, k1, k2 = ideal.coefficients
    if not (p2 > 0 and k2 > 0):
        raise CompensatorError(f"the measured force does not grow with the flux squared (p2 = {p2:.4g}, "
                               f"MEC k2 = {k2:.4g}); is this an E-core sweep with its flux channel?")
    sign = np.sign(sum(float(np.dot(p.flux_wb - np.mean(p.flux_wb), p.current_a - np.mean(p.current_a)))
                       for p in points)) or 1.0
    kappa = sign * float(np.sqrt(p2 / k2))
    offs = (p1 / kappa - k1) / (2.0 * k2)
    # (each recording's flux was centred above: its offset is that of the centred flux)
    k0_fit = float(np.mean(p0 - k1 * offs - k2 * offs * offs))
    spread = float(np.std(p2_each) / p2) if r > 1 else 0.0
    return FluxCalibration(kappa, tuple(float(o) for o in offs), StaticLaw(k0_fit, k1, k2, ideal.magnet), spread)


def _unpack(x: np.ndarray, h_scale: float) -> dict:
    jirr, cg, sg, wl, cl, sl, j1, h1, j2, h2 = np.exp(x[:10])
    return material_dict(jirr, [(_KINDS[0], 1.0, cg, sg), (_KINDS[1], wl, cl, sl)], [(j1, h1), (j2, h2)], h_scale)


def _start(hc: float, spread: float) -> np.ndarray:
    return np.log([1.3, hc, spread * hc, 1.0, 1.4 * hc, 2.0 * spread * hc, 0.3, 8.0 * hc, 1.0, 1.0e4])


def fit_hysteresis_eddy(points: Sequence[PeriodData], ideal: StaticLaw, scaling: IronScaling, response: Response,
                        *, n_fit: int = FIT_POINTS, max_nfev: int = 200) -> HysteresisEddyModel:
    """Identify the model from ``points`` (recordings of one rig: several frequencies and
    amplitudes); ``ideal`` is the MEC's law with ideal iron, ``response`` the force instrument's."""
    if len(points) < 2:
        raise CompensatorError(f"hysteresis_eddy fit needs at least 2 recordings, got {len(points)}")
    cal = calibrate_flux(points, ideal, response)
    law = cal.law
    rs = [(resample(p.current_a, n_fit), resample(p.flux_wb - np.mean(p.flux_wb), n_fit)) for p in points]
    js = [cal.kappa_a_per_wb * phi + c for (_, phi), c in zip(rs, cal.offsets_a)]
    ds = [i - j for (i, _), j in zip(rs, js)]
    djs = [derivative(j, p.frequency_hz) for j, p in zip(js, points)]
    weights = [np.abs(law.slope(j)) / max(p.force_range_n, 1e-12) for j, p in zip(js, points)]
    hc = coercive_guess(ds, scaling)
    h_scale = hc / 3.0
    bad = np.full(sum(d.size for d in ds), 1.0)

    def residual(x: np.ndarray) -> np.ndarray:
        try:
            iron = PreisachHysteresis(preisach_params(_unpack(x, h_scale), FIT_TABLES))
            tau = x[10] * 1e-6
            out = [w * (iron_drop(iron, scaling, j) + tau * dj - d) for j, d, dj, w in zip(js, ds, djs, weights)]
            res = np.concatenate(out)
            return res if np.all(np.isfinite(res)) else bad
        except (ConfigError, CompensatorError, ValueError, FloatingPointError):
            return bad

    lo = np.log([0.05, hc / 20, hc / 200, 1e-3, hc / 20, hc / 200, 1e-4, hc / 10, 1e-4, 10 * hc])
    hi = np.log([5.0, hc * 20, hc * 20, 1e3, hc * 50, hc * 50, 5.0, 1e6, 5.0, 1e7])
    best = None
    for spread in START_SPREADS:  # the narrow start converges in ~20 evaluations; the wide one is a fallback
        x0 = np.clip(np.append(_start(hc, spread), 5.0), np.append(lo, 0.0) + 1e-9, np.append(hi, 1e3) - 1e-9)
        sol = least_squares(residual, x0, bounds=(np.append(lo, 0.0), np.append(hi, 1e3)), x_scale=1.0,
                            diff_step=1e-4, max_nfev=max_nfev, ftol=1e-5, xtol=1e-6)
        if best is None or sol.cost < best.cost:
            best = sol
        if sol.success and np.all(np.isfinite(sol.fun)) and sol.cost < 0.5 * bad.size:
            break
    material = _unpack(best.x, h_scale)
    model = HysteresisEddyModel(law, scaling, material, float(best.x[10] * 1e-6))
    fit_res = [np.max(np.abs(w * (model.iron_drop(j) + model.tau_s * dj - d)))
               for j, d, dj, w in zip(js, ds, djs, weights)]
    model.report = {
        "flux_calibration": cal.as_dict(),
        "coercive_guess_A_per_m": hc,
        "cost": float(best.cost), "nfev": int(best.nfev), "status": int(best.status),
        "max_weighted_residual_pct": {p.name: 100.0 * float(v) for p, v in zip(points, fit_res)},
        "recordings": [p.name for p in points],
    }
    return model
