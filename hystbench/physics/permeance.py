"""Airgap and leakage permeances (Roters-type flux tubes).

Permeances, not reluctances, because parallel paths add.  Every function accepts complex ``z`` so
that derivatives can be taken by the complex step (exact to rounding, no step-size tuning).
"""

from __future__ import annotations

import numpy as np
from scipy.constants import mu_0

__all__ = ["gap_permeance", "edge_fringing_permeance", "slot_leakage_permeance", "mu_0"]


def edge_fringing_permeance(z: complex | np.ndarray, edge_length_m: float, fringe_height_m: float
                            ) -> complex | np.ndarray:
    """Fringing permeance of one pole edge facing a flat mover across an airgap ``z``.

    Flux leaves the side of the tooth at height r (0..h) above the pole face and reaches the mover
    along a straight run z plus a quarter circle of radius r, so
    P = ∫0^h mu0 L dr / (z + pi r / 2) = (2 mu0 L / pi) ln(1 + pi h / (2 z)).
    """
    return 2.0 * mu_0 * edge_length_m / np.pi * np.log(1.0 + np.pi * fringe_height_m / (2.0 * z))


def gap_permeance(z: complex | np.ndarray, width_m: float, depth_m: float, fringe_height_m: float = 0.0
                  ) -> complex | np.ndarray:
    """Permeance of a rectangular pole face ``width x depth`` across ``z``, with fringing on all
    four edges when ``fringe_height_m > 0`` (0 gives the closed form mu0 A / z)."""
    p = mu_0 * width_m * depth_m / z
    if fringe_height_m > 0.0:
        perimeter = 2.0 * (width_m + depth_m)
        p = p + edge_fringing_permeance(z, perimeter, fringe_height_m)
    return p


def slot_leakage_permeance(slot_width_m: float, slot_height_m: float, depth_m: float) -> float:
    """Leakage permeance across one coil slot, referred to the full coil MMF.

    For a coil filling the slot uniformly the MMF across the slot grows linearly with height, so the
    flux linkage per ampere-turn squared is mu0 * depth * height / (3 * width).
    """
    return mu_0 * depth_m * slot_height_m / (3.0 * slot_width_m)
