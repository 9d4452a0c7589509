"""The iron models a material file can choose (hystbench/physics/iron.py): the complex permeability's
elliptic loops and the E-core's flux lag it causes, Rayleigh's law (cube-law loss, amplitude
permeability, return-point memory, the Rayleigh region), and their refusals.  Expected values come
from the laws themselves, computed here from the material's constants, never from the code's output."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from scipy.constants import mu_0

from hystbench.analysis.method import measure_delays
from hystbench.config import load_material, load_rig
from hystbench.errors import ConfigError
from hystbench.physics.iron import ComplexPermeabilityIron, RayleighIron, iron_model
from hystbench.physics.presets import ecore_mec
from hystbench.sim_backend.recordings import simulate_recording
from hystbench.sim_backend.rig import SimulatedRig

QUIET = {"sensor_noise": False, "adc_quantisation": False, "lamination_eddy_currents": False}


def _with_iron(rig: str, material: str) -> dict:
    p = {k: v for k, v in load_rig(rig).items() if k != "_source"}
    p["iron"] = dict(p["iron"], material=material)
    p["effects"] = {k: v for k, v in p["effects"].items() if k != "iron_saturation"}
    return p


# --- complex permeability ----------------------------------------------------------------------
def test_complex_permeability_loop_is_an_ellipse_with_its_loss_angle():
    """The toroid (flux-controlled, sinusoidal B) on SiFe-elliptic: H = a B + b dB/dt exactly, with
    b omega / a = tan(delta) and a = Re 1/(mu0 (mu' - j mu''))."""
    mat = load_material("SiFe-elliptic")["permeability"]
    mu_re, delta = mat["mu_r_real"], math.radians(mat["loss_angle_deg"])
    p = _with_iron("toroid", "SiFe-elliptic")
    rig = SimulatedRig(p, frequency_hz=80.0, current_pp_a=1.6, effects=QUIET, seed=2)
    ch = rig.read(5000).channels
    ring = p["toroid"]
    area = (ring["outer_radius_m"] - ring["inner_radius_m"]) * ring["height_m"]
    path = math.pi * (ring["inner_radius_m"] + ring["outer_radius_m"])
    h = ch["current_A"] * p["coil"]["turns"] / path
    b = ch["flux_Wb"] / area
    db_dt = -ch["sense_V"] / (p["sense"]["turns"] * area)
    assert np.ptp(b) == pytest.approx(1.6, rel=1e-3)  # 1.6 A-pp at 1 T/A: Bmax 0.8 T
    (a, k), *_ = np.linalg.lstsq(np.column_stack([b, db_dt]), h, rcond=None)
    residual = h - a * b - k * db_dt
    assert np.sqrt(np.mean(residual**2)) < 1e-9 * np.sqrt(np.mean(h**2))
    omega = 2 * math.pi * rig.generator_frequency_hz
    assert k * omega / a == pytest.approx(math.tan(delta), rel=1e-9)
    assert a == pytest.approx((1 / (mu_0 * complex(mu_re, -mu_re * math.tan(delta)))).real, rel=1e-9)
    # the ellipse's half-width at B = 0 is Hm sin(delta)
    hm = (np.max(h) - np.min(h)) / 2
    near0 = np.abs(b) < 2e-3
    assert np.max(np.abs(h[near0])) == pytest.approx(hm * math.sin(delta), rel=5e-3)


def test_complex_permeability_without_static_hysteresis_is_lossless():
    p = _with_iron("toroid", "SiFe-elliptic")
    ch = SimulatedRig(p, frequency_hz=80.0, current_pp_a=1.6, seed=2,
                      effects={**QUIET, "static_hysteresis": False}).read(2500).channels
    b, h = ch["flux_Wb"], ch["current_A"]
    assert abs(np.corrcoef(b, h)[0, 1]) > 1 - 1e-12  # a line, no loop


@pytest.mark.parametrize("rig, ipp", [("ecore", 1.27), ("ecore_pm", 1.4)])
def test_ecore_flux_lags_current_by_the_complex_reluctance_angle(rig: str, ipp: float):
    """Flux behind current = arg(1 + R_fe Lambda11): the iron's complex reluctance l nu / A in
    series with the airgaps' 1/Lambda11 (ideal-iron coil-port permeance), eddy currents off."""
    p = _with_iron(rig, "SiFe-elliptic")
    iron = load_material("SiFe-elliptic")["permeability"]
    mu = complex(iron["mu_r_real"], -iron["mu_r_real"] * math.tan(math.radians(iron["loss_angle_deg"])))
    mec = ecore_mec(p)
    g = mec.geometry
    r_fe = g.iron_path_length_m / (mu_0 * mu * g.middle_area_m2)
    lam11 = float(np.real(mec.port_permeances(g.airgap_m)[0]))
    expected = math.degrees(np.angle(1 + r_fe * lam11))
    rec = simulate_recording(p, 320.0, ipp, 0.1, seed=4,
                             effects={"lamination_eddy_currents": False, "magnet_eddy_currents": False})
    d = measure_delays(rec)
    se = 360 * d.frequency_hz * d.delays_std_s["hysteresis"]
    assert 0.3 < expected < 3.0  # a lag worth measuring
    assert abs(d.phase_deg("hysteresis") - expected) < 4 * se, (d.phase_deg("hysteresis"), expected, se)


def test_complex_permeability_follows_a_change_of_frequency():
    """The loss term nu''/omega dB/dt is rebuilt for the new period: the lag is the same angle at
    another frequency (a frequency-independent loss angle), and the stream stays continuous."""
    p = _with_iron("ecore", "SiFe-elliptic")
    rig = SimulatedRig(p, frequency_hz=160.0, current_pp_a=1.0, effects=QUIET, seed=1)
    first = rig.read(20000).channels["flux_Wb"]
    rig.set_excitation(frequency_hz=400.0)
    second = rig.read(20000).channels["flux_Wb"]
    step = np.max(np.abs(np.diff(first))) * 400 / 160 * 1.2  # the largest step one sample may take
    assert abs(second[0] - first[-1]) < step
    lags = []
    for f in (160.0, 400.0):
        d = measure_delays(simulate_recording(p, f, 1.0, 0.1, seed=1, effects=QUIET))
        lags.append(d.phase_deg("hysteresis"))
    assert lags[0] == pytest.approx(lags[1], abs=0.01)


def test_an_iron_without_saturation_refuses_the_iron_saturation_effect():
    p = _with_iron("ecore_pm", "SiFe-elliptic")
    for material in ("SiFe-elliptic", "SiFe-rayleigh"):
        p["iron"]["material"] = material
        with pytest.raises(ConfigError, match=r"iron_saturation.*has no saturation"):
            SimulatedRig(p, effects={"iron_saturation": True})


# --- Rayleigh ----------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def rayleigh():
    m = load_material("SiFe-rayleigh")["rayleigh"]
    mu_i, v = m["initial_mu_r"], m["hysteresis_coefficient_m_per_a"]
    # the IEC law inverted to first order: nu_i = 1/(mu0 mu_i), c = v / (mu0^2 mu_i^3)
    return iron_model(load_material("SiFe-rayleigh")), 1 / (mu_0 * mu_i), v / (mu_0**2 * mu_i**3), m


def _loop(model, bm: float, bias: float = 0.0, n: int = 40001):
    """Two cycles of B = bias + bm sin from the demagnetised state (reaching the bias first); the
    second cycle's (B, H)."""
    theta = np.linspace(0.0, 4 * np.pi, n)
    b = bias + bm * np.sin(theta)
    if bias:
        b = np.concatenate([np.linspace(0.0, bias, 200, endpoint=False), b])
    h, _ = model.field(b, model.initial_state())
    return b[-(n // 2 + 1):], h[-(n // 2 + 1):]


def test_rayleigh_loop_area_is_four_thirds_c_bm_cubed(rayleigh):
    model, nu_i, c, _ = rayleigh
    amps = np.array([0.03, 0.06, 0.12])
    areas = []
    for bm in amps:
        b, h = _loop(model, bm)
        area = abs(np.trapezoid(h, b))  # the closed loop's integral of H dB
        assert area == pytest.approx(4 / 3 * c * bm**3, rel=1e-4)
        areas.append(area)
    slope = np.polyfit(np.log(amps), np.log(areas), 1)[0]
    assert slope == pytest.approx(3.0, abs=1e-3)


def test_rayleigh_loops_about_a_bias_follow_the_same_law(rayleigh):
    model, nu_i, c, _ = rayleigh
    b, h = _loop(model, 0.05, bias=0.8)
    assert abs(np.trapezoid(h, b)) == pytest.approx(4 / 3 * c * 0.05**3, rel=1e-4)
    assert np.ptp(h) / np.ptp(b) == pytest.approx(nu_i - c * 0.05, rel=1e-6)


def test_rayleigh_amplitude_permeability_grows_linearly(rayleigh):
    """Hm / Bm = nu_i - c Bm (a line in Bm); and to first order the IEC form mu_amp = mu_i + v Hm."""
    model, nu_i, c, m = rayleigh
    amps = np.linspace(0.01, 0.15, 8)
    recip = []
    for bm in amps:
        b, h = _loop(model, bm, n=8001)
        recip.append(np.ptp(h) / np.ptp(b))
    fit = np.polyfit(amps, recip, 1)
    assert fit[0] == pytest.approx(-c, rel=1e-6) and fit[1] == pytest.approx(nu_i, rel=1e-6)
    bm = 0.01
    hm = recip[0] * bm
    x = c * bm / nu_i  # the expansion's small parameter
    assert bm / (mu_0 * hm) == pytest.approx(m["initial_mu_r"] + m["hysteresis_coefficient_m_per_a"] * hm,
                                              rel=3 * x * x)


def test_rayleigh_has_return_point_memory(rayleigh):
    """A minor loop inside a branch closes on its turning point, and the branch then goes on as if
    the minor loop had never been (wiping out)."""
    model, *_ = rayleigh
    down = np.linspace(0.1, -0.1, 401)
    up = np.linspace(-0.1, 0.1, 401)
    start = np.concatenate([np.linspace(0.0, 0.1, 201), down[1:]])
    minor = np.concatenate([np.linspace(-0.1, 0.04, 281)[1:], np.linspace(0.04, -0.02, 121)[1:],
                            np.linspace(-0.02, 0.04, 121)[1:], np.linspace(0.04, 0.1, 121)[1:]])
    plain = up[1:]
    h_minor, _ = model.field(np.concatenate([start, minor]), model.initial_state())
    h_plain, _ = model.field(np.concatenate([start, plain]), model.initial_state())
    b_minor = np.concatenate([start, minor])
    first_turn = start.size + 279  # B = 0.04, the minor loop's turning point
    closing = start.size + 279 + 240  # back at B = 0.04 after the minor loop
    assert b_minor[first_turn] == pytest.approx(0.04) and b_minor[closing] == pytest.approx(0.04)
    assert h_minor[closing] == pytest.approx(h_minor[first_turn], rel=1e-12, abs=1e-12)
    # after the minor loop: the same H as without it, at the same B
    tail_b = b_minor[closing:]
    assert np.allclose(h_minor[closing:], np.interp(tail_b, up, h_plain[start.size - 1:]), rtol=0, atol=1e-9)
    assert h_minor[-1] == pytest.approx(h_plain[-1], abs=1e-9)  # the major loop closes at its tip


def test_rayleigh_refuses_a_loop_wider_than_its_region(rayleigh):
    model, nu_i, c, m = rayleigh
    region = m["region_t"]
    b = 1.05 * region * np.sin(np.linspace(0, 4 * np.pi, 2001))
    with pytest.raises(ConfigError) as info:
        model.field(b, model.initial_state())
    msg = str(info.value)
    assert "SiFe-rayleigh" in msg and "[rayleigh] region_t" in msg and f"{region:.4g} T" in msg
    ok = 0.98 * region * np.sin(np.linspace(0, 4 * np.pi, 2001))
    assert np.all(np.isfinite(model.field(ok, model.initial_state())[0]))


def test_a_rayleigh_region_past_zero_slope_is_refused_naming_file_key_and_limit(tmp_path: Path):
    mu_i, v = 1000.0, 10.0
    limit = mu_0 * mu_i**2 / (2 * v)  # where nu_i - 2 c Bm = 0
    path = tmp_path / "R.toml"
    path.write_text(f'model = "rayleigh"\n[rayleigh]\ninitial_mu_r = {mu_i}\nhysteresis_coefficient_m_per_a = {v}\n'
                    f"region_t = {limit * 1.01}\n", encoding="utf-8")
    with pytest.raises(ConfigError) as info:
        load_material(path)
    msg = str(info.value)
    assert msg.startswith(str(path)) and "[rayleigh] region_t" in msg and f"{limit:.4g} T" in msg
    path.write_text(path.read_text().replace(f"region_t = {limit * 1.01}", f"region_t = {limit * 0.99}"))
    assert isinstance(iron_model(load_material(path)), RayleighIron)


def test_rayleigh_ecore_lag_grows_with_amplitude():
    """Rate-independent loss (4/3) c Bm^3 against the stored ~Bm^2: the static lag grows with the
    amplitude (the M330-50A-free signature of Rayleigh's law), eddy currents off."""
    p = _with_iron("ecore_pm", "SiFe-rayleigh")
    quiet = {"lamination_eddy_currents": False, "magnet_eddy_currents": False}
    lags = [measure_delays(simulate_recording(p, 320.0, ipp, 0.05, seed=1, effects=quiet)).phase_deg("hysteresis")
            for ipp in (0.3, 0.75, 1.5)]
    assert 0 < lags[0] < lags[1] < lags[2]
    assert lags[2] / lags[0] == pytest.approx(1.5 / 0.3, rel=0.3)  # sin(delta) ~ Bm to first order


def test_material_models_are_chosen_by_the_model_key(tmp_path: Path):
    assert isinstance(iron_model(load_material("SiFe-elliptic")), ComplexPermeabilityIron)
    path = tmp_path / "X.toml"
    path.write_text('model = "jiles-atherton"\n', encoding="utf-8")
    with pytest.raises(ConfigError, match=r"model: must be one of preisach-factorised, complex-permeability, rayleigh"):
        load_material(path)
    path.write_text('model = "complex-permeability"\n[permeability]\nmu_r_real = 2000\nloss_angle_deg = 90\n')
    with pytest.raises(ConfigError, match=r"\[permeability\] loss_angle_deg: must be in \[0, 90\)"):
        load_material(path)
    path.write_text('model = "complex-permeability"\n[permeability]\nmu_r_real = 2000\nloss_angle_deg = 10\n')
    from hystbench.physics.hysteresis import PreisachHysteresis

    with pytest.raises(ConfigError, match="not a Preisach model"):
        PreisachHysteresis.from_config(load_material(path))
