"""The simulated rig: streaming contract, determinism, and the measurement chain's physics against
closed forms.  Iron hysteresis is switched off here where a closed form is needed (linear iron)."""

import time

import numpy as np
import pytest

from hystbench import jit
from hystbench.blocks import BlockFlags
from hystbench.errors import ConfigError
from hystbench.physics.instrument import InstrumentModel
from hystbench.physics.permeance import mu_0
from hystbench.sim_backend.actuators import ecore
from hystbench.sim_backend.rig import SimulatedRig

LINEAR = {"static_hysteresis": False, "iron_saturation": False}
QUIET = {"sensor_noise": False, "adc_quantisation": False}


@pytest.fixture(params=[False, pytest.param(True, marks=pytest.mark.skipif(not jit.enabled(), reason="no numba"))],
                ids=["numpy", "kernel"])
def ecore_path(request, monkeypatch):
    """The E-core actuator's numpy code or its numba kernels (the block-cut contract holds on both)."""
    monkeypatch.setattr(ecore, "KERNEL", request.param)


def phase_at(x, fs, f, k=1):
    """Phase (rad) of harmonic k by an explicit DFT over whole periods (independent of the code)."""
    n = int(np.floor(len(x) * f / fs) * fs / f)
    t = np.arange(n) / fs
    return np.angle(np.sum((x[:n] - x[:n].mean()) * np.exp(-2j * np.pi * k * f * t)))


def lag_deg(a, b, fs, f, k=1):
    """How far b lags a at harmonic k, degrees, wrapped to (-180, 180]."""
    d = np.degrees(phase_at(a, fs, f, k) - phase_at(b, fs, f, k))
    return (d + 180) % 360 - 180


@pytest.mark.parametrize("rig", ["ecore", "ecore_pm", "voicecoil_ferrite"])
def test_channels_follow_the_recording_format(rig):
    block = SimulatedRig(rig, effects=LINEAR).read(100)
    expected = {"current_A", "force_N", "command_V"} | ({"flux_Wb", "sense_V"} if "ecore" in rig else set())
    assert set(block.channels) == expected
    assert block.first_index == 0 and block.fs_hz == 100_000.0


def test_same_seed_same_samples_any_block_cut(ecore_path):
    effects = {**LINEAR, "mains_pickup": True, "channel_skew": True, "amplifier_distortion": True}
    a = SimulatedRig("ecore_pm", seed=7, effects=effects).record(0.02, block_size=333)
    b = SimulatedRig("ecore_pm", seed=7, effects=effects).record(0.02, block_size=2000)
    for name in a.channels:
        scale = np.max(np.abs(a.channels[name]))
        # linear iron and eddy currents are solved exactly: equal to rounding
        np.testing.assert_allclose(a.channels[name], b.channels[name], rtol=0, atol=1e-10 * scale)


def test_different_seeds_differ_only_by_noise():
    a = SimulatedRig("ecore_pm", seed=1, effects=LINEAR).record(0.05)
    b = SimulatedRig("ecore_pm", seed=2, effects=LINEAR).record(0.05)
    d = a.channels["force_N"] - b.channels["force_N"]
    # two independent N(0, s^2) draws: std of the difference is s*sqrt(2); preset s = 0.03 N
    assert np.std(d) / np.sqrt(2) == pytest.approx(0.03, rel=0.03)


def test_quantisation_rounds_to_the_lsb_and_flags_clipping():
    rig = SimulatedRig("ecore_pm", effects={**LINEAR, "sensor_noise": False,
                                            "adc_quantisation": {"current_a": 0.5}})
    block = rig.read(2000)
    lsb = 2 * 0.5 / 2**16
    i = block.channels["current_A"]
    np.testing.assert_allclose(i / lsb, np.round(i / lsb), atol=1e-6)
    assert i.max() < 0.5 and BlockFlags.CLIP in block.flags  # 0.7 A peak on a 0.5 A range


def test_measured_force_lags_current_by_the_instrument_phase():
    # Ferrite voice coil: no actuator phase (paper Sec. IV), so force-behind-current = instrument.
    rig = SimulatedRig("voicecoil_ferrite", effects={**QUIET, "frame_resonance": False}, frequency_hz=320.0)
    block = rig.record(0.5)
    f = rig.generator_frequency_hz
    measured = lag_deg(block.channels["current_A"], block.channels["force_N"], rig.fs_hz, f)
    assert measured == pytest.approx(-InstrumentModel().phase_deg(f), abs=0.002)


def test_eddy_lag_of_the_flux_matches_the_linear_circuit():
    # Linear iron, laminations only: b (1 + k nu + j w k c) = g N i  ->  lag = atan(w k c / (1 + k nu))
    from hystbench.physics.eddy import lamination_eddy_coefficient
    from hystbench.physics.presets import ecore_mec
    from hystbench.config import load_rig

    preset = load_rig("ecore")
    rig = SimulatedRig(preset, effects={**LINEAR, **QUIET}, frequency_hz=320.0)
    mec = ecore_mec(preset)
    a11 = mec.flux_coefficients(mec.geometry.airgap_m).coil_leg[0]
    kappa = a11 * mec.geometry.iron_path_length_m / mec.geometry.middle_area_m2
    nu = 1 / (mu_0 * preset["iron"]["linear_mu_r"])
    c = lamination_eddy_coefficient(preset["iron"]["conductivity_s_per_m"], preset["iron"]["lamination_thickness_m"])
    f = rig.generator_frequency_hz
    expected = np.degrees(np.arctan(2 * np.pi * f * kappa * c / (1 + kappa * nu)))
    block = rig.record(0.25)
    measured = lag_deg(block.channels["current_A"], block.channels["flux_Wb"], rig.fs_hz, f)
    assert measured == pytest.approx(expected, rel=0.01)


def test_sense_voltage_is_minus_turns_times_flux_rate():
    rig = SimulatedRig("ecore_pm", effects={**LINEAR, **QUIET})
    block = rig.record(0.02, block_size=500)
    dphi = np.gradient(block.channels["flux_Wb"], 1 / rig.fs_hz)
    np.testing.assert_allclose(block.channels["sense_V"][1:-1], -10 * dphi[1:-1],
                               atol=2e-3 * np.max(np.abs(block.channels["sense_V"])))


def test_generator_clock_is_off_nominal():
    rig = SimulatedRig("ecore_pm", effects=LINEAR, frequency_hz=320.0)
    assert rig.generator_frequency_hz == pytest.approx(320.0 * (1 + 25e-6))


def test_output_off_means_no_current():
    rig = SimulatedRig("ecore_pm", effects={**LINEAR, **QUIET})
    rig.output_enabled = False
    rig.read(5000)  # let filters settle
    assert np.max(np.abs(rig.read(1000).channels["current_A"])) == 0.0


def test_realtime_pacing_is_never_faster_than_the_adc():
    rig = SimulatedRig("voicecoil_ferrite")
    start = time.monotonic()
    n = sum(b.n for b in rig.blocks(block_size=1000, duration_s=0.1, pace="realtime"))
    assert n == 10_000 and time.monotonic() - start >= 0.1 - 1e-3


def test_bad_settings_are_refused_with_the_reason():
    with pytest.raises(ConfigError, match="fs/2"):
        SimulatedRig("ecore_pm", effects=LINEAR, frequency_hz=60_000.0)
    with pytest.raises(ConfigError, match="unknown rig 'nope'"):
        SimulatedRig("nope")


def test_block_cut_with_preisach_iron_changes_nothing_measurable(ecore_path):
    # The iron's nonlinear remainder is a fixed point whose last pass depends on the cut; its
    # residual sits at current reversals, where the inverse Preisach branch is stiff.  It must stay
    # far below the sensor noise: < 1e-4 of each channel's range (noise is ~3e-4 of the force range).
    for f in (40.0, 480.0):
        a = SimulatedRig("ecore_pm", seed=3, effects=QUIET, frequency_hz=f).record(0.03, block_size=700)
        b = SimulatedRig("ecore_pm", seed=3, effects=QUIET, frequency_hz=f).record(0.03, block_size=5000)
        for name in a.channels:
            scale = np.ptp(a.channels[name])
            np.testing.assert_allclose(a.channels[name], b.channels[name], rtol=0, atol=1e-4 * scale)


def test_a_refused_block_leaves_the_rig_as_it_was(monkeypatch):
    """The actuator refuses a block (SimulationError): asked again, the rig gives the very samples a
    rig that never failed gives (the generator's phase and the sample index did not move on)."""
    from hystbench.errors import SimulationError

    kw = dict(seed=4, effects=QUIET, frequency_hz=320.0, warmup_s=0.0)
    clean, failing = SimulatedRig("ecore_pm", **kw), SimulatedRig("ecore_pm", **kw)
    first = clean.read(700)
    assert np.array_equal(failing.read(700).channels["force_N"], first.channels["force_N"])
    real = failing.actuator.step

    def refuse_once(*args):
        monkeypatch.setattr(failing.actuator, "step", real)
        raise SimulationError("ecore_pm: refused once")

    monkeypatch.setattr(failing.actuator, "step", refuse_once)
    with pytest.raises(SimulationError, match="refused once"):
        failing.read(900)
    again, reference = failing.read(900), clean.read(900)
    assert again.first_index == reference.first_index == 700
    for name, x in reference.channels.items():
        assert np.array_equal(again.channels[name], x), name


def test_skip_keeps_the_clock_and_the_generator_phase():
    """A skipped stretch is as if simulated once the rig has settled: the same samples follow (the
    replay of a bench day skips its pauses this way)."""
    quiet = {"sensor_noise": False, "adc_quantisation": False}
    ran, skipped = (SimulatedRig("ecore_pm", fs_hz=50e3, effects=quiet, frequency_hz=120.0) for _ in range(2))
    ran.read(40_000)
    skipped.skip(37_000)  # then 3000 samples (7 periods) of settling
    skipped.read(3_000)
    assert skipped.next_index == ran.next_index
    a, b = ran.read(2_000), skipped.read(2_000)
    for ch in ("current_A", "flux_Wb", "force_N"):
        scale = np.max(np.abs(a.channels[ch]))
        assert np.max(np.abs(a.channels[ch] - b.channels[ch])) < 1e-4 * scale, ch  # the iron's memory: 2e-5
    with pytest.raises(ConfigError, match="skip must be >= 0"):
        ran.skip(-1)
