"""Eddy currents: laminated iron and solid magnets.

A conducting slab of thickness d in a field varying at angular frequency w carries eddy currents
that reduce and delay the flux: mu_eff = mu tanh(k d/2)/(k d/2), k = sqrt(j w mu sigma).  Below the
skin-depth limit this is the same as an extra field H_e = sigma d^2/12 dB/dt, which is what the
time-domain simulator uses (vectorised, no state beyond one previous sample).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike
from scipy.constants import mu_0

__all__ = [
    "slab_permeability_factor",
    "lamination_eddy_coefficient",
    "cylinder_eddy_coefficient",
    "slab_time_constant",
    "skin_depth",
]


def skin_depth(frequency_hz: ArrayLike, mu_r: float, sigma_s_per_m: float) -> float | np.ndarray:
    """sqrt(2 / (w mu sigma)) (m): a part much thinner than this carries the field whole, so the
    low-frequency eddy model (:func:`lamination_eddy_coefficient`) holds for it."""
    return np.sqrt(2.0 / (2 * np.pi * np.asarray(frequency_hz, float) * mu_0 * mu_r * sigma_s_per_m))


def slab_permeability_factor(frequency_hz: ArrayLike, mu_r: float, sigma_s_per_m: float, thickness_m: float
                             ) -> np.ndarray:
    """mu_eff / mu = tanh(kd/2)/(kd/2) for a lamination of thickness d (complex; phase < 0 = lag)."""
    f = np.asarray(frequency_hz, dtype=float)
    k = np.sqrt(1j * 2 * np.pi * f * mu_0 * mu_r * sigma_s_per_m)
    x = k * thickness_m / 2.0
    with np.errstate(invalid="ignore", divide="ignore"):
        out = np.tanh(x) / x
    return np.where(f == 0, 1.0 + 0j, out)


def lamination_eddy_coefficient(sigma_s_per_m: float, thickness_m: float) -> float:
    """sigma d^2 / 12 (A s / (m T)): H_e = this * dB/dt, the low-frequency limit of the slab."""
    return sigma_s_per_m * thickness_m**2 / 12.0


def cylinder_eddy_coefficient(sigma_s_per_m: float, radius_m: float) -> float:
    """sigma a^2 / 8: mean eddy field per dB/dt of a solid cylinder with axial flux (magnet piece)."""
    return sigma_s_per_m * radius_m**2 / 8.0


def slab_time_constant(sigma_s_per_m: float, thickness_m: float, mu_r: float = 1.0) -> float:
    """mu sigma d^2 / 12: the first-order lag that the slab's response tends to at low frequency."""
    return mu_0 * mu_r * lamination_eddy_coefficient(sigma_s_per_m, thickness_m)
