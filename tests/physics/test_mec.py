"""The E-core MEC against an independent route (Maxwell stress on the gap faces), reciprocity,
and the paper's operating points."""

import math

import numpy as np
import pytest
from scipy.constants import mu_0

from hystbench.config import load_rig
from hystbench.physics import presets
from hystbench.physics.mec import ECoreGeometry, ECoreMEC, Magnet

GEO = ECoreGeometry(outer_tooth_width_m=10e-3, middle_tooth_width_m=20e-3, depth_m=20e-3,
                    slot_width_m=10e-3, slot_height_m=20e-3, airgap_m=0.3e-3, coil_turns=150,
                    iron_path_length_m=0.1, middle_tooth_recess_m=1e-3, fringe_height_m=0.0)


def maxwell_force(flux_mid, flux_outer, geo):
    """Maxwell stress B^2 A / (2 mu0) summed over the three uniform gap faces."""
    return flux_mid**2 / (2 * mu_0 * geo.middle_area_m2) + 2 * flux_outer**2 / (2 * mu_0 * geo.outer_area_m2)


@pytest.mark.parametrize("current", [-1.0, 0.3, 0.7])
def test_force_without_magnet_equals_maxwell_stress(current):
    mec = ECoreMEC(GEO, None, tip_leakage=False)
    z = GEO.airgap_m
    # Series circuit: middle gap z + recess, two outer gaps in parallel.
    r = (z + GEO.middle_tooth_recess_m) / (mu_0 * GEO.middle_area_m2) + z / (mu_0 * 2 * GEO.outer_area_m2)
    phi = GEO.coil_turns * current / r
    assert mec.force(current) == pytest.approx(maxwell_force(phi, phi / 2, GEO), rel=1e-9)


@pytest.mark.parametrize("current", [-0.7, 0.0, 0.7])
def test_force_with_magnet_equals_maxwell_stress(current):
    magnet = Magnet(length_m=1e-3, remanence_t=1.2, recoil_mu_r=1.05)
    mec = ECoreMEC(GEO, magnet, tip_leakage=False)
    z = GEO.airgap_m
    r = (magnet.length_m / (mu_0 * magnet.recoil_mu_r * GEO.middle_area_m2) + z / (mu_0 * GEO.middle_area_m2)
         + z / (mu_0 * 2 * GEO.outer_area_m2))
    mmf = GEO.coil_turns * current + magnet.remanence_t / (mu_0 * magnet.recoil_mu_r) * magnet.length_m
    phi = mmf / r
    assert mec.force(current) == pytest.approx(maxwell_force(phi, phi / 2, GEO), rel=1e-9)


def test_mutual_permeance_is_reciprocal():
    mec = ECoreMEC(GEO, Magnet(1e-3, 1.2), iron_mu_r=2000.0)
    c1, m1, _, _ = mec._branch_fluxes(GEO.airgap_m, 1.0, 0.0)
    c2, m2, _, _ = mec._branch_fluxes(GEO.airgap_m, 0.0, 1.0)
    assert c2 == pytest.approx(m1, rel=1e-12)


def test_force_is_minus_coenergy_gradient_by_finite_differences():
    # Independent of the complex step: central differences of W' = 1/2 s^T Lambda s.
    geo = ECoreGeometry(**{**GEO.__dict__, "fringe_height_m": 5e-3})
    mec = ECoreMEC(geo, Magnet(1e-3, 1.2), iron_mu_r=3000.0)
    s = np.array([geo.coil_turns * 0.4, mec.magnet_mmf_a])

    def coenergy(z):
        l11, l12, l22 = mec.port_permeances(z)
        return 0.5 * (l11 * s[0] ** 2 + 2 * l12 * s[0] * s[1] + l22 * s[1] ** 2)

    z, h = geo.airgap_m, 1e-8
    expected = -(coenergy(z + h) - coenergy(z - h)) / (2 * h)
    assert mec.force(0.4) == pytest.approx(expected, rel=1e-6)


def test_eq1_terms_sum_to_the_force():
    base = presets.ecore_mec(load_rig("ecore_pm"))
    mec = ECoreMEC(base.geometry, base.magnet, iron_mu_r=3000.0)
    z, n1, i = mec.geometry.airgap_m, mec.geometry.coil_turns, 0.5
    eq1 = -(n1 * i**2 / 2 * mec.dphi_coil_dz(z) + mec.magnet_mmf_a / 2 * mec.dphi_pm_self_dz(z)
            + n1 * i * mec.dphi_pm_dz(z))
    assert eq1 == pytest.approx(mec.force(i), rel=1e-12)


def test_force_grows_as_the_gap_closes():
    mec = presets.ecore_mec(load_rig("ecore_pm"), linear_iron=True)
    f = mec.force_map([0.0, 0.5], np.linspace(0.1e-3, 1.5e-3, 30))
    assert np.all(np.diff(f, axis=1) < 0)


@pytest.mark.parametrize("rig, ipp, lo, hi", [("ecore", 1.27, 0.0, 3.3), ("ecore_pm", 1.4, 125.0, 220.0)])
def test_presets_land_on_the_papers_operating_points(rig, ipp, lo, hi):
    # Paper Sec. VI: 0-3.3 N at 1.27 A-pp without magnet, 125-220 N at 1.4 A-pp with it (within 10 %).
    mec = presets.ecore_mec(load_rig(rig), linear_iron=True)
    f = mec.force(np.linspace(-ipp / 2, ipp / 2, 1001))
    assert f.min() == pytest.approx(lo, abs=0.1 * max(lo, 1.0) if lo else 0.05)
    assert f.max() == pytest.approx(hi, rel=0.10)


def test_ideal_iron_is_the_limit_of_permeable_iron():
    g = load_rig("ecore_pm")
    ideal = presets.ecore_mec(g)
    nearly = ECoreMEC(ideal.geometry, ideal.magnet, iron_mu_r=1e9)
    assert nearly.force(0.3) == pytest.approx(ideal.force(0.3), rel=1e-6)
    assert math.isinf(ideal.iron_mu_r)


@pytest.mark.parametrize("rig", ["ecore", "ecore_pm"])
def test_operating_point_iron_reduces_to_the_iron_reluctance_when_both_permeabilities_agree(rig):
    # Two formulations: an iron reluctance in the coil leg of the network, and the ideal-iron
    # circuit driven by the coil MMF less the iron's drop.  With one permeability they must agree.
    base = presets.ecore_mec(load_rig(rig))
    network = ECoreMEC(base.geometry, base.magnet, iron_mu_r=2500.0)
    linearised = ECoreMEC(base.geometry, base.magnet, iron_mu_r=2500.0, iron_incremental_mu_r=2500.0)
    z = np.array([0.15e-3, 0.2e-3, 0.6e-3])
    for a, b in zip(network.force_coefficients(z), linearised.force_coefficients(z)):
        np.testing.assert_allclose(b, a, rtol=1e-9, atol=1e-9)


def test_lower_incremental_permeability_lowers_the_gain_not_the_bias():
    base = presets.ecore_mec(load_rig("ecore_pm"))
    stiff = ECoreMEC(base.geometry, base.magnet, iron_mu_r=30000.0, iron_incremental_mu_r=30000.0)
    soft = ECoreMEC(base.geometry, base.magnet, iron_mu_r=30000.0, iron_incremental_mu_r=2500.0)
    z = base.geometry.airgap_m
    (k0s, k1s, _), (k0, k1, _) = stiff.force_coefficients(z), soft.force_coefficients(z)
    assert k0 == pytest.approx(k0s, rel=1e-12) and k1 < k1s
