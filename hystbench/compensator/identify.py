"""The iron descriptions of the best model, fitted on a sweep.

1. :func:`.calibration.calibrate` gives the static law, the flux-to-current map j = kappa phi + c
   and the instrument, from the sweep alone.
2. The iron's share d = i - j is described three ways, each fitted on the same j and d:
   - ``preisach`` (:mod:`.hysteresis_eddy`): a Preisach operator on B = b0 + b_per_a j plus an
     eddy term, by nonlinear least squares (the magnet's bias b0 is fitted too; b_per_a and H's
     scale only start the fit, the material parameters absorb them);
   - ``describing_function`` (:mod:`.describing`): one complex gain per harmonic, smooth in
     frequency and amplitude, by linear least squares;
   - ``rayleigh_loop`` (:mod:`.rayleigh_loop`): closed-form parabolic branches (Rayleigh's law)
     between the period's turning points, by linear least squares.
3. :mod:`.choice` judges them, beside the paper's Eq. 1 and Eq. 6, on recordings of the sweep each
   was not fitted on (:func:`held_out_folds`), and chooses the best model.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np
from scipy.optimize import least_squares

from ..errors import ConfigError
from ..physics.hysteresis import PreisachHysteresis
from ..physics.instrument import InstrumentModel
from .calibration import FIT_POINTS, SweepCalibration, clean_flux
from .data import PeriodData
from .describing import DescribingFunctionModel, fit_describing_function
from .errors import CompensatorError
from .hysteresis_eddy import (FIT_TABLES, HysteresisEddyModel, IronScaling, coercive_guess, iron_drop,
                              material_dict, preisach_params)
from .lsq import scaled_lstsq, solution_covariance
from .periodic import apply_response, denoise, derivative, resample
from .rayleigh_loop import RayleighLoopModel, fit_rayleigh_loop

__all__ = ["IronData", "iron_data", "fit_hysteresis_eddy", "CANDIDATES", "held_out_folds"]

_KINDS = ("gauss", "lorentz")
#: Starting widths of the switching-field distributions, relative to the coercive guess.
START_SPREADS = (0.12, 0.3)


@dataclass(frozen=True)
class IronData:
    """What the iron descriptions are fitted on, per recording: one period of j and of the
    (denoised) coil current i, the weight of each sample -- dF/dj over the recording's force range,
    so a residual in current counts as the force error the accuracy measures -- and the force
    instrument at the recording's frequency (residuals go through it: near its resonance a loop's
    harmonics count 20-50x, as they do in what the load cell reports)."""

    points: tuple[PeriodData, ...]
    js: tuple[np.ndarray, ...]
    currents: tuple[np.ndarray, ...]
    weights: tuple[np.ndarray, ...]
    through: tuple[Callable[[np.ndarray], np.ndarray], ...]

    def subset(self, keep: Sequence[int]) -> "IronData":
        return IronData(*(tuple(x[k] for k in keep)
                          for x in (self.points, self.js, self.currents, self.weights, self.through)))


def _instrument(instrument: InstrumentModel, frequency_hz: float) -> Callable[[np.ndarray], np.ndarray]:
    """One period through the force instrument at ``frequency_hz``."""
    return lambda x: apply_response(x, frequency_hz, instrument.frequency_response)


def iron_data(points: Sequence[PeriodData], cal: SweepCalibration, n_fit: int = FIT_POINTS) -> IronData:
    js = tuple(cal.seen_current(k, resample(clean_flux(p), n_fit)) for k, p in enumerate(points))
    currents = tuple(resample(denoise(p.current_a, p.average_noise_a()), n_fit) for p in points)
    weights = tuple(np.abs(cal.law.slope(j)) / max(p.force_range_n, 1e-12) for j, p in zip(js, points))
    through = tuple(_instrument(cal.instrument, p.frequency_hz) for p in points)
    return IronData(tuple(points), js, currents, weights, through)


# --- candidate 1: Preisach iron + eddy term --------------------------------------------------------
def _unpack(x: np.ndarray, h_scale: float) -> dict:
    jirr, cg, sg, wl, cl, sl, j1, h1, j2, h2 = np.exp(x[:10])
    return material_dict(jirr, [(_KINDS[0], 1.0, cg, sg), (_KINDS[1], wl, cl, sl)], [(j1, h1), (j2, h2)], h_scale)


def _start(hc: float, spread: float) -> np.ndarray:
    return np.log([1.3, hc, spread * hc, 1.0, 1.4 * hc, 2.0 * spread * hc, 0.3, 8.0 * hc, 1.0, 1.0e4])


def fit_hysteresis_eddy(data: IronData, cal: SweepCalibration, scaling: IronScaling, *,
                        max_nfev: int = 200) -> HysteresisEddyModel:
    """The Preisach candidate on ``data``; ``scaling`` (the preset's MEC) only starts the fit: the
    magnet's bias b0 is fitted, from the law's own bias as a start."""
    if len(data.points) < 2:
        raise CompensatorError(f"hysteresis_eddy fit needs at least 2 recordings, got {len(data.points)}")
    law = cal.law
    js, weights, through = data.js, data.weights, data.through
    ds = [i - j for i, j in zip(data.currents, js)]
    djs = [derivative(j, p.frequency_hz) for j, p in zip(js, data.points)]
    magnet = law.magnet and cal.bias_current_a > 0
    b0_start = scaling.b_per_a * cal.bias_current_a if magnet else 0.0
    hc = coercive_guess(ds, scaling)
    h_scale = hc / 3.0
    bad = np.full(sum(d.size for d in ds), 1.0)

    # tau, eps and delta enter linearly: solved for at every trial iron (variable projection), so the
    # nonlinear search runs over the iron alone (10 parameters, 11 with the magnet's bias)
    lin_a = np.vstack([np.stack([h(w * dj), h(w * j), h(w)], axis=1) for j, dj, w, h in zip(js, djs, weights, through)])

    def scaling_of(x: np.ndarray) -> IronScaling:
        return IronScaling(b0_start * math.exp(x[10]) if magnet else 0.0, scaling.b_per_a, scaling.d_per_h)

    def project(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        iron = PreisachHysteresis(preisach_params(_unpack(x, h_scale), FIT_TABLES))
        sc = scaling_of(x)
        rest = np.concatenate([h(w * (iron_drop(iron, sc, j) - d)) for j, d, w, h in zip(js, ds, weights, through)])
        coef = scaled_lstsq(lin_a, -rest)
        return rest + lin_a @ coef, coef

    def residual(x: np.ndarray) -> np.ndarray:
        try:
            res = project(x)[0]
            return res if np.all(np.isfinite(res)) else bad
        except (ConfigError, CompensatorError, ValueError, FloatingPointError, IndexError, np.linalg.LinAlgError):
            return bad

    lo = np.log([0.05, hc / 20, hc / 200, 1e-3, hc / 20, hc / 200, 1e-4, hc / 10, 1e-4, 10 * hc])
    hi = np.log([5.0, hc * 20, hc * 20, 1e3, hc * 50, hc * 50, 5.0, 1e6, 5.0, 1e7])
    if magnet:
        lo, hi = np.append(lo, math.log(0.6)), np.append(hi, math.log(1.6))
    best = None
    for spread in START_SPREADS:  # the narrow start converges in ~20 evaluations; the wide one is a fallback
        x0 = np.clip(np.append(_start(hc, spread), [0.0] if magnet else []), lo + 1e-9, hi - 1e-9)
        sol = least_squares(residual, x0, bounds=(lo, hi), x_scale=1.0, diff_step=1e-4, max_nfev=max_nfev,
                            ftol=1e-5, xtol=1e-6)
        if best is None or sol.cost < best.cost:
            best = sol
        if sol.success and np.all(np.isfinite(sol.fun)) and sol.cost < 0.5 * bad.size:
            break
    if not best.cost < 0.5 * bad.size:
        raise CompensatorError("hysteresis_eddy fit: no Preisach iron describes this sweep's loops "
                               f"(cost {best.cost:.3g} after {best.nfev} evaluations)")
    res, (tau, eps, delta) = project(best.x)
    sc = scaling_of(best.x)
    model = HysteresisEddyModel(law, sc, _unpack(best.x, h_scale), float(tau), linear=float(eps),
                                offset_a=float(delta))
    se = np.sqrt(np.maximum(np.diag(solution_covariance(best.jac, res, extra_parameters=3)), 0.0))
    se_lin = np.sqrt(np.maximum(np.diag(solution_covariance(lin_a, res, extra_parameters=best.x.size)), 0.0))
    names = ["log j_irr", "log gauss centre", "log gauss width", "log lorentz weight", "log lorentz centre",
             "log lorentz width", "log J1", "log h1", "log J2", "log h2"] + (["log b0 factor"] if magnet else [])
    params = {n: [float(v), float(e)] for n, v, e in zip(names, best.x, se)}
    params.update({n: [float(v), float(e)] for n, v, e in zip(("tau_s", "eps", "delta_A"), (tau, eps, delta), se_lin)})
    fit_res = [float(np.max(np.abs(r))) for r in np.split(res, np.cumsum([j.size for j in js])[:-1])]
    model.report = {
        "parameters": params,
        "magnet_bias_T": sc.b0_t, "coercive_guess_A_per_m": hc,
        "cost": float(best.cost), "nfev": int(best.nfev), "status": int(best.status),
        "max_weighted_residual_pct": {p.name: 100.0 * float(v) for p, v in zip(data.points, fit_res)},
        "recordings": [p.name for p in data.points],
    }
    return model


# --- candidate 2: describing function --------------------------------------------------------------
def fit_describing(data: IronData, cal: SweepCalibration, scaling: IronScaling) -> DescribingFunctionModel:
    return fit_describing_function(data.js, data.currents, [p.frequency_hz for p in data.points], cal.law,
                                   [p.name for p in data.points])


# --- candidate 3: Rayleigh loops ---------------------------------------------------------------------
def fit_rayleigh(data: IronData, cal: SweepCalibration, scaling: IronScaling) -> RayleighLoopModel:
    return fit_rayleigh_loop(data.js, data.currents, [p.frequency_hz for p in data.points], data.weights, cal.law,
                             [p.name for p in data.points], data.through)


Fitter = Callable[[IronData, SweepCalibration, IronScaling], object]
#: The iron descriptions the best model chooses among (name -> fit).
CANDIDATES: dict[str, Fitter] = {"preisach": fit_hysteresis_eddy, "describing_function": fit_describing,
                                  "rayleigh_loop": fit_rayleigh}


# --- the folds the choice holds out ------------------------------------------------------------------
def held_out_folds(points: Sequence[PeriodData]) -> list[tuple[str, list[int]]]:
    """(what is held out, indices held out): each inner frequency and each inner amplitude of the
    sweep's grid in turn (interpolation, as the held-out judgement will ask), else one recording."""
    freqs = sorted({round(p.nominal_frequency_hz, 6) for p in points})
    amps = sorted({round(p.current_pp_a, 6) for p in points})
    folds = []
    for f in freqs[1:-1]:
        folds.append((f"{f:g} Hz", [k for k, p in enumerate(points) if round(p.nominal_frequency_hz, 6) == f]))
    for a in amps[1:-1]:
        folds.append((f"{a:g} A-pp", [k for k, p in enumerate(points) if round(p.current_pp_a, 6) == a]))
    if not folds:
        folds = [(points[k].name, [k]) for k in range(1, len(points) - 1)]
    return [(n, k) for n, k in folds if 0 < len(k) < len(points) - 2]
