"""The E-core's magnetics, from a reluctance network: why each piece is what it is.

Geometry: an E-core (coil on the middle tooth, sense coil on an outer tooth) facing a flat mover;
the middle tooth, twice as wide as an outer one, is recessed by ``recess_m`` where the magnet sits.
By symmetry each outer leg carries Phi and the middle leg 2 Phi, and the iron (same B = Phi / A_o in
every leg) is one path of length ``iron_path_m``.  One loop (middle leg + one outer leg):

    N i + M_pm = Phi [R_out(g) + 2 R_mid(g)] + l_fe H_fe + 2 G_m d(Phi)/dt

Gap permeances carry Roters-style side fringing, P = mu0 [A/g + (perimeter/pi) ln(1 + pi t/g)].
The force is Maxwell's on each gap at constant flux, F = sum 1/2 Phi_k^2 dR_k/dg, which
:func:`coenergy_force` checks by virtual work on W'(MMF, g).

Iron: H_fe = nu B (1 + (|B|/B_knee)^p) + h_bw + eddy.  h_bw is a Bouc-Wen hysteretic field driven by
B (rate-independent).  The laminations' eddy currents come from a Cauer ladder: the half-lamination
cut into layers, each storing flux (mu h) and joined by eddy-current paths (1/sigma), so the surface
reluctivity is nu / mu_eff(jw), exact for a linear slab as the layers grow (tanh law; tested).
The magnet, a solid disc, is a shorted turn: its eddy MMF is G_m dPhi_m/dt with G_m = sigma h / 4 pi.

Everything runs in periodic steady state (harmonic balance on one period): the bench is recorded
after it settles, and the clocks and skews then only decide where in the period each sample falls.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

MU0 = 4e-7 * np.pi


@dataclass(frozen=True)
class ECoreGeometry:
    """Dimensions near the paper's actuator (0-3.3 N without, 125-220 N with magnet at ~1.3 A-pp)."""

    turns: int = 520
    outer_width_m: float = 7e-3
    depth_m: float = 25e-3
    gap_m: float = 0.5e-3
    recess_m: float = 2.75e-3
    fringe_extent_m: float = 1.0e-3
    iron_path_m: float = 0.15
    iron_mu_r: float = 600.0
    magnet_length_m: float = 2.75e-3
    magnet_mu_r: float = 1.05
    magnet_hc_a_per_m: float = 9.1e5

    @property
    def outer_area_m2(self) -> float:
        return self.outer_width_m * self.depth_m

    @property
    def middle_area_m2(self) -> float:
        return 2 * self.outer_width_m * self.depth_m


def gap_permeance(g: np.ndarray | float, width_m: float, depth_m: float, extent_m: float
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Permeance of one tooth's gap with side fringing, and its derivative in g (H, H/m)."""
    g = np.asarray(g, float)
    area, perim = width_m * depth_m, 2 * (width_m + depth_m)
    p = MU0 * (area / g + perim / np.pi * np.log1p(np.pi * extent_m / g))
    dp = -MU0 * (area / g**2 + perim * extent_m / (g * (g + np.pi * extent_m)))
    return p, dp


def loop_reluctance(geo: ECoreGeometry, g: np.ndarray | float, magnet: bool
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(R_loop, dR_out/dg, dR_mid_air/dg) of the one-loop circuit, air and magnet only (A/Wb)."""
    g = np.asarray(g, float)
    p_out, dp_out = gap_permeance(g, geo.outer_width_m, geo.depth_m, geo.fringe_extent_m)
    # the magnet fills the recess; without it the middle gap is air over the whole recess
    g_mid = g if magnet else g + geo.recess_m
    p_mid, dp_mid = gap_permeance(g_mid, 2 * geo.outer_width_m, geo.depth_m, geo.fringe_extent_m)
    r_out, r_mid = 1 / p_out, 1 / p_mid
    if magnet:
        r_mid = r_mid + geo.magnet_length_m / (MU0 * geo.magnet_mu_r * geo.middle_area_m2)
    return r_out + 2 * r_mid, -dp_out / p_out**2, -dp_mid / p_mid**2


def gap_force(geo: ECoreGeometry, phi_outer: np.ndarray, g: np.ndarray | float, magnet: bool) -> np.ndarray:
    """Attractive force (N) at constant flux: two outer gaps with Phi, the middle one with 2 Phi."""
    _, dr_out, dr_mid = loop_reluctance(geo, g, magnet)
    return phi_outer**2 * dr_out + 2 * phi_outer**2 * dr_mid


def magnet_mmf(geo: ECoreGeometry) -> float:
    """The magnet as an MMF source in the middle leg: Hc l_pm (A)."""
    return geo.magnet_hc_a_per_m * geo.magnet_length_m


def anhysteretic_field(b: np.ndarray, nu: float, knee_t: float | None, power: float) -> np.ndarray:
    """H(B) of the reversible iron: linear, or saturating past its own knee (A/m)."""
    h = nu * b
    if knee_t is not None:
        h = h * (1 + np.abs(b / knee_t) ** power)
    return h


def static_flux_outer(geo: ECoreGeometry, mmf: np.ndarray, g: float, magnet: bool,
                      knee_t: float | None = None, power: float = 8.0) -> np.ndarray:
    """Phi (Wb) of the anhysteretic network for a total loop MMF (A), by bisection: the loop's
    MMF is monotone in Phi, so this is robust with any knee."""
    mmf = np.asarray(mmf, float)
    r_loop = float(loop_reluctance(geo, g, magnet)[0])
    nu = 1 / (MU0 * geo.iron_mu_r)
    a = geo.outer_area_m2
    lo = -np.abs(mmf) / r_loop - 1e-12
    hi = np.abs(mmf) / r_loop + 1e-12
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        need = mid * r_loop + geo.iron_path_m * anhysteretic_field(mid / a, nu, knee_t, power)
        below = need < mmf
        lo, hi = np.where(below, mid, lo), np.where(below, hi, mid)
    return 0.5 * (lo + hi)


def coenergy_force(geo: ECoreGeometry, mmf: float, g: float, magnet: bool, knee_t: float | None = None,
                   dg: float = 1e-8, n: int = 2001) -> float:
    """F = dW'/dg at constant MMF, W'(U, g) = integral_0^U Phi_mid dU' (both outer loops): virtual
    work on a co-energy map, independent of the gap-flux formula it checks."""
    def w(gg: float) -> float:
        u = np.linspace(0.0, mmf, n)
        phi_mid = 2 * static_flux_outer(geo, u, gg, magnet, knee_t)
        return float(np.sum((phi_mid[1:] + phi_mid[:-1]) * np.diff(u)) / 2)
    return -(w(g + dg) - w(g - dg)) / (2 * dg)  # attraction: co-energy grows as the gap closes


def ladder_reluctivity_factor(omega: np.ndarray, mu: float, sigma: float, thickness_m: float,
                              layers: int) -> np.ndarray:
    """nu_surface / nu at each omega for a lamination, from its Cauer ladder (finite-difference
    half-lamination, ``layers`` cells, symmetry at the centre): the mean B of the cells over mu H at
    the surface, inverted.  Exact for the tanh law as ``layers`` grows."""
    omega = np.atleast_1d(np.asarray(omega, float))
    h = thickness_m / 2 / layers
    out = np.ones(omega.shape, complex)
    # cells k = 1..layers; H_0 is the surface, d2H/dx2 = j w sigma mu H, zero slope at the centre
    for idx, w in enumerate(omega):
        if w == 0:
            continue
        c = 1j * w * sigma * mu * h * h
        main = np.full(layers, -(2 + c), complex)
        main[-1] = -(1 + c)  # mirror cell at the centre
        lower = np.ones(layers - 1, complex)
        mat = np.diag(main) + np.diag(lower, 1) + np.diag(lower, -1)
        rhs = np.zeros(layers, complex)
        rhs[0] = -1.0  # H_0 = 1 at the surface (cell 1 sits h/2 deep: its link to the surface is h/2)
        mat[0, 0] = -(3 + c)  # half-length link to the surface node: conductance 2/h
        rhs[0] = -2.0
        hk = np.linalg.solve(mat, rhs)
        out[idx] = 1 / np.mean(hk)
    return out


def slab_reluctivity_factor(omega: np.ndarray, mu: float, sigma: float, thickness_m: float) -> np.ndarray:
    """The closed form the ladder approaches: mu / mu_eff = (k a) / tanh(k a), k = sqrt(j w mu sigma)."""
    ka = np.sqrt(1j * np.asarray(omega, float) * mu * sigma) * thickness_m / 2
    with np.errstate(invalid="ignore", divide="ignore"):
        f = ka / np.tanh(ka)
    return np.where(np.abs(ka) < 1e-9, 1.0 + 0j, f)


def bouc_wen_field(b: np.ndarray, a: float, beta: float, gamma: float, h0: float = 0.0) -> tuple[np.ndarray, float]:
    """Bouc-Wen (n = 1) hysteretic field along a B path: dh/dB = A - beta sgn(dB) h - gamma |h|.
    Linear in h on each step with fixed signs, so each step is an exact exponential."""
    out = np.empty_like(b)
    h = h0
    prev = b[0]
    for k in range(b.size):
        db = b[k] - prev
        prev = b[k]
        if db != 0.0:
            s = 1.0 if db > 0 else -1.0
            c = beta * s + gamma * (1.0 if h >= 0 else -1.0)
            if abs(c) < 1e-12:
                h = h + a * db
            else:
                hinf = a / c
                h = hinf + (h - hinf) * math.exp(-c * db)
        out[k] = h
    return out, h


def periodic_bouc_wen(b: np.ndarray, a: float, beta: float, gamma: float) -> np.ndarray:
    """The steady loop of a periodic B (one period given): run a settling period, then record."""
    _, h_end = bouc_wen_field(np.concatenate([b, b[:1]]), a, beta, gamma)
    _, h_end = bouc_wen_field(np.concatenate([b, b[:1]]), a, beta, gamma, h_end)
    out, _ = bouc_wen_field(b, a, beta, gamma, h_end)
    return out
