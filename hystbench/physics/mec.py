"""Magnetic equivalent circuit (MEC) of the E-core reluctance actuator (paper Sec. II A, Fig. 2).

Nodes: B (back iron and both outer teeth, the reference), M (top of the middle tooth, under the
coil), P (face of the magnet, or of the middle tooth without magnet) and X (the mover).

    B --[coil N1 i, iron P_fe]--> M --[magnet Hc lpm, P_pm]--> P --[middle gap]--> X --[2 outer gaps]--> B
    M --[slot leakage]--> B          P --[tip leakage]--> B

The circuit is linear in its two MMF sources, so it is summarised by a 2x2 port-permeance matrix
Lambda(z) (coil port, magnet port).  The co-energy is W' = 1/2 s^T Lambda s with s = (N1 i, Hc lpm)
and the attractive force is F = -dW'/dz (the paper's Eq. 1, term by term:
F = -[N1 i^2/2 dphi_coil/dz + Hc lpm/2 dphi_pm_self/dz + N1 i dphi_pm/dz]).
Derivatives in z are taken by the complex step, so they are exact to rounding.
Without magnet the middle tooth is still the shorter one: its gap is z + lpm.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from .permeance import gap_permeance, mu_0, slot_leakage_permeance

__all__ = ["ECoreGeometry", "Magnet", "ECoreMEC", "FluxCoefficients"]

_STEP = 1e-30  # complex-step size (m); any tiny value works


@dataclass(frozen=True)
class Magnet:
    """Permanent magnet on the middle tooth, magnetised along the tooth."""

    length_m: float
    remanence_t: float
    recoil_mu_r: float = 1.05
    conductivity_s_per_m: float = 0.0

    @property
    def coercivity_a_per_m(self) -> float:
        """Hc of the linear recoil line, Br / (mu0 mu_r)."""
        return self.remanence_t / (mu_0 * self.recoil_mu_r)


@dataclass(frozen=True)
class ECoreGeometry:
    """Dimensions of the E-core and its mover (SI units)."""

    outer_tooth_width_m: float
    middle_tooth_width_m: float
    depth_m: float
    slot_width_m: float
    slot_height_m: float
    airgap_m: float
    coil_turns: int
    iron_path_length_m: float
    middle_tooth_recess_m: float  # the middle tooth is shorter by this (room for the magnet)
    fringe_height_m: float = 0.0  # 0 switches fringing off

    @property
    def middle_area_m2(self) -> float:
        return self.middle_tooth_width_m * self.depth_m

    @property
    def outer_area_m2(self) -> float:
        return self.outer_tooth_width_m * self.depth_m


@dataclass(frozen=True)
class FluxCoefficients:
    """Fluxes as linear functions of the two MMFs: phi = a * F_coil + b * F_magnet (Wb per A)."""

    coil_leg: tuple[float, float]
    magnet: tuple[float, float]
    outer_tooth: tuple[float, float]
    middle_gap: tuple[float, float]


class ECoreMEC:
    """Linear MEC of the E-core.  ``iron_mu_r = inf`` gives ideal iron (the simulator then adds the
    iron's own MMF drop from the material model); a finite value puts a linear iron reluctance in
    the coil leg, which is what the paper's non-hysteretic analytical model does."""

    def __init__(self, geometry: ECoreGeometry, magnet: Magnet | None = None,
                 iron_mu_r: float = math.inf, tip_leakage: bool = True,
                 iron_incremental_mu_r: float | None = None) -> None:
        self.geometry = geometry
        self.magnet = magnet
        self.iron_mu_r = iron_mu_r
        self.tip_leakage = tip_leakage
        #: With this set, the iron is linearised at its operating point: ``iron_mu_r`` is the chord
        #: permeability that carries the magnet's bias, this one the incremental (minor-loop)
        #: permeability the excitation sees.  Iron in real reluctance actuators needs both: at low
        #: induction its minor loops are far less permeable than its bias chord (Rayleigh region).
        self.iron_incremental_mu_r = iron_incremental_mu_r

    # --- sources -------------------------------------------------------------------------------
    @property
    def magnet_mmf_a(self) -> float:
        """Hc * lpm, the magnet's MMF (0 without magnet)."""
        m = self.magnet
        return 0.0 if m is None else m.coercivity_a_per_m * m.length_m

    def ideal_iron(self) -> "ECoreMEC":
        """The same circuit with infinitely permeable iron: the simulator adds the iron's MMF drop
        from its own material model, and the operating-point linearisation starts from it."""
        return ECoreMEC(self.geometry, self.magnet, math.inf, self.tip_leakage)

    def _operating_point_coefficients(self, z):
        """(k0, k1, k2) with the iron linearised at its operating point (see __init__).

        The force is that of the ideal-iron circuit at the coil MMF the airgaps see,
        F_c,eff(i) = F_c0 + g N1 i: the bias drop F_c0 comes from the chord permeability, the gain
        g = 1 / (1 + a11 l nu_inc / A) from the incremental one (a11: coil-leg flux per MMF)."""
        g_ = self.geometry
        ideal = self.ideal_iron()
        z = np.asarray(z, dtype=float)
        a11, a12, _, _ = ideal._branch_fluxes(z, 1.0, 0.0)
        a12 = ideal._branch_fluxes(z, 0.0, 1.0)[0]
        nu_dc = 0.0 if math.isinf(self.iron_mu_r) else 1.0 / (mu_0 * self.iron_mu_r)
        nu_inc = 1.0 / (mu_0 * self.iron_incremental_mu_r)
        k_l = g_.iron_path_length_m / g_.middle_area_m2
        fm = self.magnet_mmf_a
        fc0 = -k_l * nu_dc * a12 * fm / (1.0 + a11 * k_l * nu_dc)  # bias drop: -l nu_dc B0
        gain = 1.0 / (1.0 + a11 * k_l * nu_inc)
        d = ideal._dz(lambda q: np.stack(ideal.port_permeances(q)), z)
        n1 = g_.coil_turns
        k2 = -0.5 * d[0] * (gain * n1) ** 2
        k1 = -(d[0] * fc0 + d[1] * fm) * gain * n1
        k0 = -0.5 * (d[0] * fc0**2 + 2 * d[1] * fc0 * fm + d[2] * fm**2)
        return k0, k1, k2

    # --- network ------------------------------------------------------------------------------
    def _permeances(self, z):
        g = self.geometry
        p_out = gap_permeance(z, g.outer_tooth_width_m, g.depth_m, g.fringe_height_m)
        p_leak = 2.0 * slot_leakage_permeance(g.slot_width_m, g.slot_height_m, g.depth_m)
        if self.magnet is None:  # the recess is air in series with the gap: one longer gap
            p_mid = gap_permeance(z + g.middle_tooth_recess_m, g.middle_tooth_width_m, g.depth_m,
                                  g.fringe_height_m)
            p_pm, p_tip = math.inf, 0.0
        else:
            p_mid = gap_permeance(z, g.middle_tooth_width_m, g.depth_m, g.fringe_height_m)
            p_pm = mu_0 * self.magnet.recoil_mu_r * g.middle_area_m2 / self.magnet.length_m
            p_tip = (2.0 * mu_0 * g.depth_m * self.magnet.length_m / g.slot_width_m
                     if self.tip_leakage else 0.0)
        p_fe = (math.inf if math.isinf(self.iron_mu_r)
                else mu_0 * self.iron_mu_r * g.middle_area_m2 / g.iron_path_length_m)
        return p_out, p_mid, p_pm, p_tip, p_leak, p_fe

    def _branch_fluxes(self, z, f_coil, f_magnet):
        """Fluxes (coil leg, magnet, one outer tooth, middle gap) for the MMFs at airgap ``z``.

        Two eliminations: the middle path M -> X -> B is a linear two-port in (u_M, F_magnet);
        then the coil leg fixes u_M (directly for ideal iron, through P_fe otherwise)."""
        p_out, p_mid, p_pm, p_tip, p_leak, p_fe = self._permeances(np.asarray(z))
        p_ret = 2.0 * p_out  # both outer gaps, from X back to B

        def middle_path(u_m, f_m):
            if math.isinf(p_pm):  # P is M: gap in series with the return gaps
                phi = u_m * p_mid * p_ret / (p_mid + p_ret)
                return phi, phi / p_ret
            # node P: p_pm (u_m + f_m - u_p) = p_tip u_p + p_gx u_p, with the gap+return in series
            p_gx = p_mid * p_ret / (p_mid + p_ret)
            u_p = p_pm * (u_m + f_m) / (p_pm + p_tip + p_gx)
            phi_gap = p_gx * u_p
            return p_pm * (u_m + f_m - u_p), phi_gap / p_ret

        if math.isinf(p_fe):
            u_m = np.asarray(f_coil)
        else:  # p_fe (F_coil - u_m) = p_leak u_m + phi_mag(u_m, F_magnet), linear in u_m
            y_mm, _ = middle_path(1.0, 0.0)
            y_mf, _ = middle_path(0.0, 1.0)
            u_m = (p_fe * f_coil - y_mf * f_magnet) / (p_fe + p_leak + y_mm)
        phi_mag, u_x = middle_path(u_m, f_magnet)
        phi_coil = p_leak * u_m + phi_mag
        phi_outer = p_out * u_x
        return phi_coil, phi_mag, phi_outer, 2.0 * phi_outer

    def port_permeances(self, z: ArrayLike) -> tuple[complex | np.ndarray, complex | np.ndarray,
                                                      complex | np.ndarray]:
        """(Lambda11, Lambda12, Lambda22): coil-port and magnet-port fluxes per unit MMF."""
        c1, m1, _, _ = self._branch_fluxes(z, 1.0, 0.0)
        c2, m2, _, _ = self._branch_fluxes(z, 0.0, 1.0)
        return c1, 0.5 * (c2 + m1), m2  # reciprocity: c2 == m1 up to rounding

    def flux_coefficients(self, z: float) -> FluxCoefficients:
        """Every branch flux per unit coil and magnet MMF at ``z``: what the simulator superposes
        each sample (the circuit is linear), so it solves the network once, not per sample."""
        c1, m1, o1, g1 = self._branch_fluxes(z, 1.0, 0.0)
        c2, m2, o2, g2 = self._branch_fluxes(z, 0.0, 1.0)
        pair = lambda a, b: (float(np.real(a)), float(np.real(b)))  # noqa: E731
        return FluxCoefficients(pair(c1, c2), pair(m1, m2), pair(o1, o2), pair(g1, g2))

    def port_permeance_derivatives(self, z: float) -> tuple[np.ndarray, np.ndarray]:
        """(dLambda/dz, d2Lambda/dz2) as arrays [L11, L12, L22] at ``z`` (the second by a central
        difference of the complex-step first derivative)."""
        d1 = lambda zz: np.array(self._dz(lambda q: np.stack(self.port_permeances(q)), zz))  # noqa: E731
        h = 1e-3 * z
        return d1(z), (d1(z + h) - d1(z - h)) / (2 * h)

    # --- paper quantities ------------------------------------------------------------------------
    def _dz(self, fun, z):
        z = np.asarray(z, dtype=float)
        return np.imag(fun(z + 1j * _STEP)) / _STEP

    def phi_coil(self, z: ArrayLike) -> float | np.ndarray:
        """phi_coil(z) = N1 * Lambda11: coil flux per ampere (Wb/A)."""
        return self.geometry.coil_turns * np.real(self.port_permeances(z)[0])

    def phi_pm(self, z: ArrayLike) -> float | np.ndarray:
        """Magnet flux through the coil leg (Wb), Hc lpm * Lambda12."""
        return self.magnet_mmf_a * np.real(self.port_permeances(z)[1])

    def phi_pm_self(self, z: ArrayLike) -> float | np.ndarray:
        """Magnet flux through the magnet itself (Wb), Hc lpm * Lambda22."""
        return self.magnet_mmf_a * np.real(self.port_permeances(z)[2])

    def dphi_coil_dz(self, z: ArrayLike) -> float | np.ndarray:
        """d phi_coil / dz (Wb/(A m)): with N1, the coil's i^2 term of the force (Eq. 1)."""
        return self._dz(lambda zz: self.geometry.coil_turns * self.port_permeances(zz)[0], z)

    def dphi_pm_dz(self, z: ArrayLike) -> float | np.ndarray:
        """d phi_pm / dz (Wb/m): with N1, the linear term of the force, coil and magnet together."""
        return self._dz(lambda zz: self.magnet_mmf_a * self.port_permeances(zz)[1], z)

    def dphi_pm_self_dz(self, z: ArrayLike) -> float | np.ndarray:
        """d phi_pm_self / dz (Wb/m): with Hc lpm, the magnet's own pull, the force at zero current."""
        return self._dz(lambda zz: self.magnet_mmf_a * self.port_permeances(zz)[2], z)

    def force_coefficients(self, z: ArrayLike) -> tuple[float | np.ndarray, float | np.ndarray,
                                                         float | np.ndarray]:
        """(k0, k1, k2) with F(i) = k0 + k1 i + k2 i^2 at airgap z: the paper's Eq. (1)."""
        if self.iron_incremental_mu_r is not None:
            return self._operating_point_coefficients(z)
        n1 = self.geometry.coil_turns
        fm = self.magnet_mmf_a
        k2 = -0.5 * n1 * self.dphi_coil_dz(z)
        k1 = -n1 * self.dphi_pm_dz(z)
        k0 = -0.5 * fm * self.dphi_pm_self_dz(z)
        return k0, k1, k2

    def force(self, current_a: ArrayLike, z: ArrayLike | None = None) -> np.ndarray:
        """Attractive force (N) for coil current ``current_a`` at airgap ``z`` (default: nominal)."""
        z = self.geometry.airgap_m if z is None else z
        k0, k1, k2 = self.force_coefficients(z)
        i = np.asarray(current_a, dtype=float)
        return k0 + k1 * i + k2 * i * i

    def force_map(self, current_a: ArrayLike, z_m: ArrayLike) -> np.ndarray:
        """F on the grid current x airgap (the paper's Fig. 3)."""
        i, z = np.meshgrid(np.asarray(current_a, float), np.asarray(z_m, float), indexing="ij")
        k0, k1, k2 = self.force_coefficients(z)
        return k0 + k1 * i + k2 * i * i
