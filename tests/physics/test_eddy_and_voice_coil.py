"""Eddy-current models against their asymptotes, and the voice coil against the paper's Fig. 7c."""

import numpy as np
import pytest
from scipy.constants import mu_0

from hystbench.config import load_rig
from hystbench.physics import presets
from hystbench.physics.eddy import (lamination_eddy_coefficient, skin_depth,
                                    slab_permeability_factor, slab_time_constant)


def test_slab_low_frequency_limit_is_the_sigma_d2_over_12_field():
    mu_r, sigma, d, f = 3000.0, 2.2e6, 0.5e-3, 5.0
    k = slab_permeability_factor(f, mu_r, sigma, d)
    # tanh(x)/x = 1 - x^2/3 + ..., x^2 = j w mu sigma d^2/4  ->  phase = -w mu sigma d^2 / 12
    expected = -2 * np.pi * f * mu_0 * mu_r * lamination_eddy_coefficient(sigma, d)
    assert np.angle(k) == pytest.approx(expected, rel=1e-3)


def test_slab_high_frequency_limit_is_two_skin_depths_over_thickness():
    mu_r, sigma, d, f = 3000.0, 2.2e6, 0.5e-3, 500_000.0
    delta = skin_depth(f, mu_r, sigma)
    assert d / delta > 20
    # tanh -> 1: mu_eff/mu = 2/(k d) = (1 - j) delta / d
    assert slab_permeability_factor(f, mu_r, sigma, d) == pytest.approx((1 - 1j) * delta / d, rel=1e-9)


@pytest.mark.parametrize("rig", ["voicecoil_ndfeb", "voicecoil_smco"])
def test_conducting_magnets_lag_about_15_degrees_at_3_khz(rig):
    # Paper Sec. IV B: ~15 deg extra phase at 3 kHz relative to ferrite.
    vc = presets.voice_coil(load_rig(rig))
    ferrite = presets.voice_coil(load_rig("voicecoil_ferrite"))
    lag = np.degrees(np.angle(ferrite.frequency_response(3000.0)) - np.angle(vc.frequency_response(3000.0)))
    assert lag == pytest.approx(15.0, abs=1.5)


def test_ferrite_voice_coil_adds_no_phase():
    vc = presets.voice_coil(load_rig("voicecoil_ferrite"))
    assert abs(np.degrees(np.angle(vc.frequency_response(3000.0)))) < 1e-3


def test_time_constant_scales_with_conductivity():
    assert slab_time_constant(2e6, 1e-2) == pytest.approx(2 * slab_time_constant(1e6, 1e-2))
