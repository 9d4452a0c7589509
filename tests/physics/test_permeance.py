"""Airgap permeances against closed forms and an independent quadrature."""

import numpy as np
import pytest
from scipy.constants import mu_0
from scipy.integrate import quad

from hystbench.physics.permeance import edge_fringing_permeance, gap_permeance, slot_leakage_permeance


def test_simple_gap_is_mu0_area_over_length():
    # The textbook reluctance of a uniform gap: R = z / (mu0 A).
    z, w, d = 0.5e-3, 10e-3, 20e-3
    assert 1.0 / gap_permeance(z, w, d) == pytest.approx(z / (mu_0 * w * d), rel=1e-15)


def test_fringing_equals_the_flux_tube_integral():
    # Tubes of length z + pi r / 2 leaving the tooth side at height r, integrated numerically.
    z, length, h = 0.3e-3, 60e-3, 5e-3
    expected, _ = quad(lambda r: mu_0 * length / (z + np.pi * r / 2), 0, h)
    assert edge_fringing_permeance(z, length, h) == pytest.approx(expected, rel=1e-10)


def test_fringing_adds_permeance_and_fades_for_small_gaps():
    w, d, h = 10e-3, 20e-3, 5e-3
    z = np.array([0.05e-3, 0.2e-3, 1e-3, 5e-3])
    plain, fringed = gap_permeance(z, w, d), gap_permeance(z, w, d, h)
    assert np.all(fringed > plain)
    # fringing grows like ln(1/z) while the face grows like 1/z: its share shrinks as the gap closes
    share = (fringed - plain) / fringed
    assert np.all(np.diff(share) > 0)
    assert share[0] < 0.05


def test_slot_leakage_of_a_uniformly_filled_slot():
    # Energy of a linearly rising MMF across a slot: W = mu0 d h / (3 s) * (N I)^2 / 2.
    s, h, d = 10e-3, 20e-3, 20e-3
    assert slot_leakage_permeance(s, h, d) == pytest.approx(mu_0 * d * h / (3 * s))
