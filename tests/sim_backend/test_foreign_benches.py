"""The foreign benches (hystbench/sim_backend/benches.py): each loads as a rig preset that looks like
its nominal rig, simulates without clipping over the sweep's range, and differs from the nominal
as it declares (force law, iron, instrument); its truth is the MEC's at its own geometry."""

from __future__ import annotations

import math

import numpy as np
import pytest

from hystbench.config import load_material, load_rig
from hystbench.errors import ConfigError
from hystbench.physics.mec import ECoreGeometry, ECoreMEC, Magnet
from hystbench.physics.presets import ecore_mec
from hystbench.sim_backend.benches import FOREIGN_BENCHES, IRONS, bench_truth, foreign_preset
from hystbench.sim_backend.recordings import clipped_channels, simulate_recording, simulated_sweep

NAMES = list(FOREIGN_BENCHES)
PAPER_IPP = {"ecore_pm": 1.4, "ecore": 1.27}


def test_the_family_is_one_bench_per_iron_for_each_nominal():
    assert sorted(NAMES) == sorted(f"{n}~{i}" for n in ("ecore", "ecore_pm") for i in ("m330", "m130", "elliptic",
                                                                                         "rayleigh"))
    for name, bench in FOREIGN_BENCHES.items():
        build = {k: v for k, v in bench.factors().items() if not k.startswith("instrument.")}
        assert all(0.8 <= v <= 1.2 for v in build.values())
        assert any(v > 1 for v in build.values()) and any(v < 1 for v in build.values()), name


@pytest.mark.parametrize("name", NAMES)
def test_a_foreign_bench_looks_like_its_nominal_and_differs_as_declared(name: str):
    bench = FOREIGN_BENCHES[name]
    p = foreign_preset(name)
    nominal = load_rig(bench.nominal)
    assert p["name"] == bench.nominal and ("magnet" in p) == ("magnet" in nominal)
    assert name in p["description"] and name in p["_source"]
    assert p["iron"]["material"] == IRONS[bench.iron][0]
    for key, factor in bench.geometry.items():
        assert p["geometry"][key] == pytest.approx(nominal["geometry"][key] * factor)
    assert p["coil"]["turns"] == round(nominal["coil"]["turns"] * bench.turns)
    if "magnet" in p:
        assert p["magnet"]["remanence_t"] == pytest.approx(nominal["magnet"]["remanence_t"] * bench.remanence)
    for key in ("fn_hz", "zeta_n", "f0_hz", "zeta_0"):
        assert p["instrument"][key] == pytest.approx(nominal["instrument"][key] * bench.instrument.get(key, 1.0))
    # the force law the bench really has is not the nominal's
    truth = bench_truth(name)
    mn = ecore_mec(nominal)
    k_nom = np.array(mn.force_coefficients(mn.geometry.airgap_m))
    k = np.array(truth["force_coefficients"])
    big = np.abs(k_nom) > 1e-6 * np.max(np.abs(k_nom))
    assert np.max(np.abs(k[big] / k_nom[big] - 1)) > 0.05


@pytest.mark.parametrize("name", NAMES)
def test_a_foreign_bench_simulates_at_320_hz_without_clipping(name: str):
    nominal = FOREIGN_BENCHES[name].nominal
    rec = simulate_recording(foreign_preset(name), 320.0, PAPER_IPP[nominal], 0.05, seed=3)
    assert rec.metadata["rig"] == nominal and not rec.metadata.get("clipped")
    assert all(np.all(np.isfinite(x)) and np.ptp(x) > 0 for x in rec.channels.values())


def test_every_bench_runs_the_corners_of_the_sweep_without_clipping():
    """0.3-1.5 A-pp at 40-480 Hz (the range a compensator benchmark sweeps): no SimulationError, no
    refusal of the Rayleigh region, no channel at its ADC full scale."""
    for name in NAMES:
        for rec in simulated_sweep(foreign_preset(name), [40.0, 480.0], [0.3, 1.5], duration_s=0.03, seed=5):
            assert not clipped_channels(rec) and not rec.metadata.get("clipped"), (name, rec.metadata)


def test_truth_is_the_mec_at_the_bench_geometry():
    """ecore_pm~elliptic: the ideal-iron law recomputed here from the declared factors; the linear-iron
    law with the iron's in-phase permeability |mu_r|^2 / mu'; the bias flux density in the coil leg."""
    name = "ecore_pm~elliptic"
    bench, truth = FOREIGN_BENCHES[name], bench_truth(name)
    nominal = load_rig("ecore_pm")
    g = {k: v * bench.geometry.get(k, 1.0) for k, v in nominal["geometry"].items()}
    geo = ECoreGeometry(**g, coil_turns=round(nominal["coil"]["turns"] * bench.turns))
    m = nominal["magnet"]
    magnet = Magnet(m["length_m"], m["remanence_t"] * bench.remanence, m["recoil_mu_r"], m["conductivity_s_per_m"])
    ideal = ECoreMEC(geo, magnet)
    assert truth["force_coefficients"] == pytest.approx(ideal.force_coefficients(geo.airgap_m), rel=1e-12)
    iron = load_material("SiFe-elliptic")["permeability"]
    mu1 = iron["mu_r_real"]
    mu2 = mu1 * math.tan(math.radians(iron["loss_angle_deg"]))
    linear = ECoreMEC(geo, magnet, iron_mu_r=(mu1**2 + mu2**2) / mu1)
    assert truth["force_coefficients_linear_iron"] == pytest.approx(linear.force_coefficients(geo.airgap_m), rel=1e-9)
    assert truth["loss_angle_deg"] == iron["loss_angle_deg"] and truth["iron_model"] == "complex-permeability"
    # bias: the magnet's MMF Hc lpm through the ideal-iron circuit, per middle-tooth area
    phi = ideal.magnet_mmf_a * float(np.real(ideal.port_permeances(geo.airgap_m)[1]))
    assert truth["bias_flux_density_t"] == pytest.approx(phi / (g["middle_tooth_width_m"] * g["depth_m"]), rel=1e-9)
    assert 0.5 < truth["bias_flux_density_t"] < 1.2
    assert bench_truth("ecore~rayleigh")["bias_flux_density_t"] == 0.0
    assert truth["instrument"]["fn_hz"] == pytest.approx(nominal["instrument"]["fn_hz"] * 1.03)


def test_the_elliptic_bench_mean_coil_leg_flux_is_the_linear_iron_bias():
    """With a linear iron the coil leg's DC flux density is the magnet's bias through the MEC with
    the iron's in-phase permeability (truth's linear-iron circuit), whatever the AC does."""
    from hystbench.sim_backend.rig import SimulatedRig

    name = "ecore_pm~elliptic"
    p = foreign_preset(name)
    rig = SimulatedRig(p, frequency_hz=320.0, current_pp_a=1.0, seed=1)
    b = []
    for _ in range(5):
        rig.read(3125)  # 10 periods
        b.append(rig.actuator.iron_flux_density_t.copy())
    iron = load_material("SiFe-elliptic")["permeability"]
    mu1 = iron["mu_r_real"]
    mu2 = mu1 * math.tan(math.radians(iron["loss_angle_deg"]))
    mec = ECoreMEC(ecore_mec(p).geometry, ecore_mec(p).magnet, iron_mu_r=(mu1**2 + mu2**2) / mu1)
    g = mec.geometry
    bias = mec.magnet_mmf_a * float(np.real(mec._branch_fluxes(g.airgap_m, 0.0, 1.0)[0])) / g.middle_area_m2
    assert np.mean(np.concatenate(b)) == pytest.approx(bias, rel=2e-3)


def test_an_unknown_bench_is_refused_naming_the_known_ones():
    with pytest.raises(ConfigError, match=r"unknown foreign bench 'ecore~steel'; known: .*ecore_pm~m330"):
        foreign_preset("ecore~steel")


@pytest.mark.parametrize(("name", "ipps"), [("ecore_pm~m130", (0.6, 0.9, 1.4)), ("ecore~m330", (0.6,))])
def test_a_whole_number_of_samples_per_period_simulates(name: str, ipps: tuple[float, ...]):
    """400 Hz at 100 kS/s is 250 samples a period: every period's sampled extrema of B tie with the
    last ones to < 1 uT, the Preisach iron's turning points nested ~20 deep during the warm-up and
    the iron's fixed point flipped for ever between the two sides of a wipe-out.  The rig refused
    it as 'driven far into saturation' at |B| = 0.88 T, far below M130-27S's knee (~1.4 T)."""
    for rec in simulated_sweep(foreign_preset(name), [400.0], ipps, seed=5020, duration_s=0.01):
        assert all(np.all(np.isfinite(x)) and np.ptp(x) > 0 for x in rec.channels.values())


def test_the_iron_at_400_hz_settles_into_a_periodic_loop_below_its_knee():
    """What the rig settled on is the iron's steady state: B repeats period after period (250
    samples; the generator's 25 ppm move it < 2e-5 T) and stays below M130-27S's knee, where the
    anhysteretic curve still takes < 50 % more H for 10 % more B (IEC 61869-2's knee point)."""
    from hystbench.config import load_material
    from hystbench.physics.hysteresis import PreisachHysteresis
    from hystbench.sim_backend.rig import SimulatedRig

    rig = SimulatedRig(foreign_preset("ecore_pm~m130"), frequency_hz=400.0, current_pp_a=1.4, seed=5020)
    rig.read(500)
    b = rig.actuator.iron_flux_density_t
    assert np.max(np.abs(b[250:] - b[:250])) < 1e-4
    peak = float(np.max(np.abs(b)))
    iron = PreisachHysteresis.from_config(load_material("M130-27S"))
    assert iron.anhysteretic_field(1.1 * peak) < 1.5 * iron.anhysteretic_field(peak)


def test_a_block_the_passes_cannot_settle_is_solved_sample_by_sample(monkeypatch: pytest.MonkeyPatch):
    """One pass allowed: no block of the M130-27S bench at 400 Hz settles by the passes, so every one
    is solved sample by sample (ECoreActuator._solve_sequential) and the samples are those the
    passes give, to the fixed point's residual (< 1e-4 of each channel's range, as a block cut).
    Rayleigh's iron has no such solve: its refusal names the bench, the operating point and the
    iron, and says it is the simulator's limit, not the bench's."""
    from hystbench.errors import SimulationError
    from hystbench.sim_backend.actuators import ecore
    from hystbench.sim_backend.rig import SimulatedRig

    quiet = {"sensor_noise": False, "adc_quantisation": False}
    kw = dict(frequency_hz=400.0, current_pp_a=1.4, seed=1, effects=quiet)
    passes = SimulatedRig(foreign_preset("ecore_pm~m130"), **kw).record(0.02, block_size=500)
    solved = []
    real = ecore.ECoreActuator._solve_sequential
    monkeypatch.setattr(ecore.ECoreActuator, "_solve_sequential", lambda self, *a: solved.append(1) or real(self, *a))
    monkeypatch.setattr(ecore, "MAX_PASSES", 1)
    monkeypatch.setattr(ecore, "KERNEL", False)  # the numpy passes check convergence only after IRON_ITERATIONS
    by_sample = SimulatedRig(foreign_preset("ecore_pm~m130"), **kw).record(0.02, block_size=500)
    assert solved
    for name, x in passes.channels.items():
        np.testing.assert_allclose(by_sample.channels[name], x, rtol=0, atol=1e-4 * np.ptp(x), err_msg=name)
    with pytest.raises(SimulationError, match="did not converge") as err:
        SimulatedRig(foreign_preset("ecore_pm~rayleigh"), frequency_hz=400.0, current_pp_a=1.4, seed=1)
    msg = str(err.value)
    assert "foreign bench ecore_pm~rayleigh" in msg and "400 Hz" in msg and "SiFe-rayleigh" in msg
    assert "not of the bench" in msg and "saturat" not in msg
