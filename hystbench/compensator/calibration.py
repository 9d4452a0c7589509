"""The static force law and the flux-to-current map of an E-core, identified from a sweep.

A bench never equals its preset, so nothing here reads the preset's geometry.  The force
instrument is given (the preset's, or better the one identified with a voice coil as in the paper's
Sec. IV: ``analysis.identification``): the E-core's own force and flux cannot tell it, because the
load cell's resonance multiplies the flux's noise 40x there and biases any fit of it (tried: fn
2.8 % off on a sweep with the paper's noise).  What one sweep of an E-core (current, flux and force
per recording, as period averages) tells:

1. Force against flux.  The gap force is one quadratic of the absolute gap flux for every
   recording of a bench, phi = phi_ac + phi0_r (the integrator loses each recording's DC), seen
   through the force instrument: F = H{P2 phi^2 + Q1 phi} + Q0.  One least-squares fit over the
   sweep gives P2, Q1, Q0 and the DC fluxes phi0_r (up to one common gauge): the DC passes the
   instrument unchanged, so it ties each recording's linear term to the shared quadratic.
2. Flux to current.  The airgaps see j = kappa phi + c, the current the flux would take with ideal
   iron; the coil current is j plus the iron's share.  Regressing i on phi over the sweep, with a
   quadrature term per recording (each loop's opening), gives kappa and c: the iron's mean in-phase
   share goes into kappa, so j is the current without the loop, and the iron models
   (:mod:`.identify`) carry a linear term for what differs from that mean.  Without a magnet the
   force's vertex is at zero current (no magnet, no flux at zero current): c is set there, k1 = 0.
3. The law F = k0 + k1 j + k2 j^2 follows from 1 and 2, with standard errors from both fits.

:func:`fit_delayed_law` is the paper's Eq. 6 law in the coil current, fitted on the same sweep.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np
from scipy.optimize import least_squares
from scipy.signal import hilbert

from ..physics.instrument import InstrumentModel
from .data import PeriodData
from .errors import CompensatorError
from .lsq import linear_fit, solution_covariance
from .periodic import apply_response, denoise, noise_floor_rms, resample, shift
from .static import StaticLaw

__all__ = ["SweepCalibration", "calibrate", "fit_delayed_law", "clean_flux", "FIT_POINTS"]

FIT_POINTS = 400  # samples per period in the fits (the loops are smooth)


@dataclass(frozen=True)
class SweepCalibration:
    """What :func:`calibrate` found (see the module docstring); ``report`` is for MODEL.json."""

    law: StaticLaw
    law_se: tuple[float, float, float]
    instrument: InstrumentModel
    kappa_a_per_wb: float
    offset_a: float
    flux_dc_wb: tuple[float, ...]
    report: dict = field(default_factory=dict)

    def seen_current(self, index: int, flux_wb: np.ndarray) -> np.ndarray:
        """j of recording ``index`` of the calibrated sweep from its (AC) flux."""
        phi = np.asarray(flux_wb, float)
        return self.kappa_a_per_wb * (phi - phi.mean() + self.flux_dc_wb[index]) + self.offset_a

    @property
    def bias_current_a(self) -> float:
        """The magnet's bias as a coil current: the law's vertex lies this far below j = 0."""
        return -self.law.flux_zero_a


def clean_flux(p: PeriodData) -> np.ndarray:
    """The AC flux of a period average with its noise-only harmonics dropped: the fits apply the
    instrument (40x gain at its resonance) to functions of it, so its noise must not go in."""
    phi = np.asarray(p.flux_wb, float) - float(np.mean(p.flux_wb))
    return denoise(phi, noise_floor_rms(phi))


def _scaled(points: Sequence[PeriodData], n: int):
    phis = [resample(clean_flux(p), n) for p in points]
    forces = [resample(np.asarray(p.force_n, float), n) for p in points]
    s_phi = max(float(np.std(x)) for x in phis) or 1.0
    s_f = max(float(np.ptp(x)) for x in forces) or 1.0
    return [x / s_phi for x in phis], [x / s_f for x in forces], s_phi, s_f


class _ForceFlux:
    """Step 1's residual: x = (P2, Q1, Q0, u0_2 .. u0_R) in scaled units (u = phi / s_phi, F / s_f)."""

    def __init__(self, points: Sequence[PeriodData], instrument: InstrumentModel, n: int) -> None:
        self.us, self.gs, self.s_phi, self.s_f = _scaled(points, n)
        self.freqs = [p.frequency_hz for p in points]
        self.weights = [1.0 / max(float(np.ptp(g)), 1e-3) for g in self.gs]  # each recording's own range
        resp = instrument.frequency_response
        # the instrument is linear: its response to (u + c)^2 and u + c from those to u^2, u and 1
        self.h_uu = [apply_response(u * u, f, resp) for u, f in zip(self.us, self.freqs)]
        self.h_u = [apply_response(u, f, resp) for u, f in zip(self.us, self.freqs)]

    def residual(self, x: np.ndarray) -> np.ndarray:
        p2, q1, q0 = x[:3]
        u0 = np.concatenate(([0.0], x[3:]))
        out = []
        for huu, hu, g, w, c in zip(self.h_uu, self.h_u, self.gs, self.weights, u0):
            out.append(w * (p2 * (huu + 2 * c * hu + c * c) + q1 * (hu + c) + q0 - g))
        return np.concatenate(out)


def _start(ff: _ForceFlux) -> np.ndarray:
    """Per-recording linear fits tied together by a shared P2, then u0_r from each recording's
    linear coefficient (P1_r = 2 P2 u0_r + Q1)."""
    rows, rhs = [], []
    r = len(ff.us)
    for k, (huu, hu, g) in enumerate(zip(ff.h_uu, ff.h_u, ff.gs)):
        cols = np.zeros((g.size, 1 + 2 * r))
        cols[:, 0] = huu
        cols[:, 1 + k] = hu
        cols[:, 1 + r + k] = 1.0
        rows.append(cols)
        rhs.append(g)
    coef = np.linalg.lstsq(np.vstack(rows), np.concatenate(rhs), rcond=None)[0]
    p2, p1 = coef[0], coef[1:1 + r]
    if not p2 > 0:
        raise CompensatorError(f"the measured force does not grow with the flux squared (P2 = {p2:.4g}); "
                               "is this an E-core sweep with its force and flux channels?")
    u0 = (p1 - p1[0]) / (2 * p2)
    return np.concatenate(([p2, p1[0], coef[1 + r]], u0[1:]))  # recording 0's u0 is the gauge (0)


def calibrate(points: Sequence[PeriodData], instrument: InstrumentModel, magnet: bool, *,
              n_fit: int = FIT_POINTS) -> SweepCalibration:
    """Steps 1-3 of the module docstring for one bench's sweep."""
    if len(points) < 2:
        raise CompensatorError(f"the static law needs at least 2 recordings of the sweep, got {len(points)}")
    ff = _ForceFlux(points, instrument, n_fit)
    sol = least_squares(ff.residual, _start(ff), x_scale="jac", max_nfev=200)
    x, resid = sol.x, sol.fun
    cov = solution_covariance(sol.jac, resid)
    force_rms = [float(np.sqrt(np.mean((r / w) ** 2))) * ff.s_f
                 for r, w in zip(np.split(resid, len(points)), ff.weights)]

    # step 2: i = kappa phi + c + a_r H{phi} per recording
    phis = [u * ff.s_phi for u in ff.us]
    u0 = np.concatenate(([0.0], x[3:])) * ff.s_phi
    currents = [resample(np.asarray(p.current_a, float), n_fit) for p in points]
    r = len(points)
    rows, rhs = [], []
    for k, (phi, c0, i) in enumerate(zip(phis, u0, currents)):
        cols = np.zeros((phi.size, 2 + r))
        cols[:, 0], cols[:, 1] = phi + c0, 1.0
        cols[:, 2 + k] = np.imag(hilbert(phi))
        w = 1.0 / max(float(np.ptp(i)), 1e-9)
        rows.append(w * cols)
        rhs.append(w * i)
    flux_map = linear_fit(np.vstack(rows), np.concatenate(rhs))
    cov_i = flux_map.cov
    kappa, c = float(flux_map.coef[0]), float(flux_map.coef[1])

    # step 3: the law in j, F = P2' phi^2 + Q1' phi + Q0 with phi = (j - c) / kappa
    p2, q1, q0 = x[0] * ff.s_f / ff.s_phi ** 2, x[1] * ff.s_f / ff.s_phi, x[2] * ff.s_f
    if not magnet:  # the vertex (zero gap flux) at j = 0
        c = kappa * q1 / (2 * p2)

    def law_of(p2_: float, q1_: float, q0_: float, kappa_: float, c_: float) -> np.ndarray:
        k2 = p2_ / kappa_ ** 2
        k1 = q1_ / kappa_ - 2 * k2 * c_
        k0 = q0_ - q1_ * c_ / kappa_ + k2 * c_ * c_
        return np.array([k0, 0.0 if not magnet else k1, k2])

    ks = law_of(p2, q1, q0, kappa, c)
    # standard errors: the delta method over (P2, Q1, Q0) of step 1 and (kappa, c) of step 2
    scale = np.array([ff.s_f / ff.s_phi ** 2, ff.s_f / ff.s_phi, ff.s_f])
    base_v = np.array([p2, q1, q0, kappa, c])
    cov5 = np.zeros((5, 5))
    cov5[:3, :3] = cov[:3, :3] * np.outer(scale, scale)
    cov5[3:, 3:] = cov_i[:2, :2]
    jac = np.zeros((3, 5))
    for k in range(5):
        h = 1e-6 * (abs(base_v[k]) + 1e-12)
        up = base_v.copy()
        up[k] += h
        jac[:, k] = (law_of(*up) - ks) / h
    law_se = tuple(float(v) for v in np.sqrt(np.maximum(np.diag(jac @ cov5 @ jac.T), 0.0)))
    law = StaticLaw(float(ks[0]), float(ks[1]), float(ks[2]), magnet)
    report = {
        "law": {**law.to_dict(), "se": {"k0_N": law_se[0], "k1_N_per_A": law_se[1], "k2_N_per_A2": law_se[2]}},
        "kappa_A_per_Wb": kappa, "kappa_se": float(math.sqrt(max(cov_i[0, 0], 0.0))), "offset_A": c,
        "magnet_bias_A": -law.flux_zero_a if magnet else 0.0,
        "force_flux_rms_residual_N": {p.name: v for p, v in zip(points, force_rms)},
        "force_flux_fit": {"cost": float(sol.cost), "nfev": int(sol.nfev), "status": int(sol.status)},
    }
    return SweepCalibration(law, law_se, instrument, kappa, c, tuple(float(v) for v in u0), report)


def fit_delayed_law(points: Sequence[PeriodData], instrument: InstrumentModel, magnet: bool, *,
                    n_fit: int = FIT_POINTS) -> tuple[StaticLaw, tuple[float, float, float]]:
    """The static law of the paper's Eq. 6 in the coil current: F = H{k0 + k1 i_d + k2 i_d^2} with
    i_d each recording's current delayed by its measured theta_hyst, by linear least squares over
    the sweep (each recording weighted by its own force range, as the accuracy counts).  Without a
    magnet k1 = 0 (the force is even in the current).  Returns the law and its standard errors."""
    rows, rhs = [], []
    for p in points:
        theta = p.theta_hyst_rad if np.isfinite(p.theta_hyst_rad) else 0.0
        i = shift(resample(denoise(p.current_a, p.average_noise_a()), n_fit), theta / (2 * np.pi))
        cols = [np.ones_like(i), apply_response(i * i, p.frequency_hz, instrument.frequency_response)]
        if magnet:
            cols.insert(1, apply_response(i, p.frequency_hz, instrument.frequency_response))
        w = 1.0 / max(p.force_range_n, 1e-12)
        rows.append(w * np.stack(cols, axis=1))
        rhs.append(w * resample(np.asarray(p.force_n, float), n_fit))
    fit = linear_fit(np.vstack(rows), np.concatenate(rhs))
    coef, se = fit.coef, fit.se
    if not magnet:
        coef, se = np.array([coef[0], 0.0, coef[1]]), np.array([se[0], 0.0, se[1]])
    if not coef[2] > 0:
        raise CompensatorError(f"the measured force does not grow with the current squared (k2 = {coef[2]:.4g})")
    return StaticLaw(float(coef[0]), float(coef[1]), float(coef[2]), magnet), tuple(float(v) for v in se)
