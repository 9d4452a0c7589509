"""A raw sense-coil voltage integrated into the flux: against closed forms, against the simulated
rig's own flux, and through the commands a bench engineer runs on such a recording."""

import json
from pathlib import Path

import numpy as np
import pytest

from hystbench.analysis.sense_coil import FLUX_FROM, integrate_sense_voltage, with_flux
from hystbench.cli.main import main as cli_main
from hystbench.errors import RecordingError
from hystbench.formats.recording import Recording, read_recording, write_recording
from hystbench.sim_backend.rig import SimulatedRig


def _fit(x: np.ndarray, t: np.ndarray, w: float) -> complex:
    """The component of x at w, as a phasor (least squares, with an offset)."""
    A = np.column_stack([np.cos(w * t), np.sin(w * t), np.ones_like(t)])
    c = np.linalg.lstsq(A, x, rcond=None)[0]
    return complex(c[0], -c[1])


@pytest.mark.parametrize("harmonic", [1, 3, 7])
def test_each_harmonic_comes_back_with_its_gain_and_phase(harmonic):
    """A flux of known harmonics (Faraday's sense_V = -N dphi/dt in closed form, an ADC offset added,
    the clock 40 ppm off so the record is not a whole number of periods): the integral's gain is
    1 to the trapezoid's corrected residue, 11 (wT)^4 / 720, and its phase is exact."""
    fs, f, turns = 100e3, 480.0 * (1 + 40e-6), 12
    t = np.arange(10_000) / fs
    w = 2 * np.pi * harmonic * f
    phi = 2e-4 * np.sin(w * t + 0.7)
    v = -turns * 2e-4 * w * np.cos(w * t + 0.7) + 3e-3
    z = _fit(integrate_sense_voltage(v, fs, turns, 480.0), t, w) / _fit(phi, t, w)
    assert abs(abs(z) - 1) < 1.2 * 11 * (w / fs) ** 4 / 720 + 1e-7  # plain means (a ramp): 4.7e-5
    assert abs(np.angle(z)) < 1e-6  # rad: 0.06 mdeg, far below the method's precision at any frequency
    est = integrate_sense_voltage(v, fs, turns, 480.0)
    assert abs(est[:10_000 - 2].mean()) < 1e-3 * 2e-4  # AC only: the offset did not ramp it


def test_the_simulated_rigs_flux_is_its_sense_voltage_integrated():
    """The simulated rig's flux state and its sense coil's voltage (its derivative, Faraday's) are two
    outputs of one simulation: integrated here, the voltage gives the flux back, to what the simulator's
    own derivative allows (it takes the iron's share by a second-order backward difference: 1.3e-5 of
    the range; by a first-order one, half a sample late, it was 2.8e-4)."""
    sim = SimulatedRig("ecore_pm", frequency_hz=320.0, effects={"sensor_noise": False, "adc_quantisation": False},
                       seed=3)
    block = sim.record(0.1)
    flux = np.asarray(block.channels["flux_Wb"])
    rec = Recording(None, sim.fs_hz, {k: v for k, v in block.channels.items() if k != "flux_Wb"}, sim.metadata())
    got = with_flux(rec)
    assert got is not rec and "flux_Wb" not in rec.channels
    err = got.channels["flux_Wb"] - flux
    assert np.max(np.abs(err - err.mean())) < 1e-4 * np.ptp(flux)
    assert "sense_V integrated" in got.metadata[FLUX_FROM]


def test_a_recording_with_its_flux_or_without_a_sense_coil_is_left_alone():
    meta = {"rig": "ecore_pm", "frequency_Hz": 100.0, "sample_rate_Hz": 1e4, "current_pp_A": 1.0}
    x = np.sin(np.arange(200) / 10)
    both = Recording(None, 1e4, {"current_A": x, "flux_Wb": x, "sense_V": x}, meta)
    neither = Recording(None, 1e4, {"current_A": x}, meta)
    assert with_flux(both) is both and with_flux(neither) is neither


@pytest.mark.parametrize("turns,why", [(None, "add 'sense_turns' to the sidecar"),
                                       (0, "positive number of turns"), ("10", "positive number of turns"),
                                       (True, "positive number of turns")])
def test_a_sense_voltage_without_its_turns_is_refused_naming_the_sidecar(tmp_path, turns, why):
    meta = {"rig": "ecore_pm", "frequency_Hz": 100.0, "sample_rate_Hz": 1e4, "current_pp_A": 1.0}
    if turns is not None:
        meta["sense_turns"] = turns
    x = np.sin(np.arange(200) / 10)
    write_recording(Recording(None, 1e4, {"current_A": x, "sense_V": x}, meta), tmp_path / "r")
    with pytest.raises(RecordingError, match=rf"^{tmp_path / 'r'}\.json: .*{why}"):
        with_flux(read_recording(tmp_path / "r"))


def _estimate(stem: Path, capsys) -> dict:
    assert cli_main(["estimate", str(stem), "--json"]) == 0
    return json.loads(capsys.readouterr().out)


def test_estimate_on_a_sense_coil_recording_gives_the_flux_recordings_delays(tmp_path, capsys):
    """The same simulated recording written twice, with the integrator's flux and with the sense coil's
    voltage only: the three delays agree within their standard errors (the two flux channels carry
    their own noise)."""
    sim = SimulatedRig("ecore_pm", frequency_hz=160.0, seed=5)
    block = sim.record(0.3)
    rec = Recording(None, sim.fs_hz, dict(block.channels), sim.metadata())
    write_recording(rec, tmp_path / "flux")
    write_recording(Recording(None, sim.fs_hz, {k: v for k, v in block.channels.items() if k != "flux_Wb"},
                              sim.metadata()), tmp_path / "sense")
    a, b = _estimate(tmp_path / "flux", capsys), _estimate(tmp_path / "sense", capsys)
    for k in ("hysteresis", "instrument", "total"):
        std = np.hypot(a["delays_std_s"][k], b["delays_std_s"][k])
        assert abs(a["delays_s"][k] - b["delays_s"][k]) < 4 * std + 1e-9, k
    assert a["delays_s"]["hysteresis"] > 10 * a["delays_std_s"]["hysteresis"]  # a delay worth comparing


def test_the_sweep_readers_of_identify_model_and_diagnose_integrate_a_sense_coil_sweep(tmp_path):
    """A sweep folder recorded without an integrator: identification's and the diagnosis's readers
    hand every recording on with its flux (the one integration, the same numbers)."""
    from hystbench.analysis.identification import read_sweeps
    from hystbench.cli.diagnose import read_inputs

    fluxes = []
    (tmp_path / "pm").mkdir()
    for f in (80.0, 160.0):
        sim = SimulatedRig("ecore_pm", frequency_hz=f, seed=7)
        block = sim.record(0.1)
        fluxes.append(with_flux(Recording(None, sim.fs_hz, {"sense_V": block.channels["sense_V"]},
                                          sim.metadata())).channels["flux_Wb"])
        write_recording(Recording(None, sim.fs_hz, {k: v for k, v in block.channels.items() if k != "flux_Wb"},
                                  sim.metadata()), tmp_path / "pm" / f"pm_{f:g}Hz")
    for recs in (read_sweeps(tmp_path / "pm")["pm"], read_inputs([tmp_path / "pm"])):
        assert [r.frequency_hz for r in recs] == [80.0, 160.0]
        for r, flux in zip(recs, fluxes):
            np.testing.assert_array_equal(r.channels["flux_Wb"], flux)
            assert FLUX_FROM in r.metadata


def test_a_diagnosis_of_integrated_sense_voltages_does_not_look_for_an_integrators_leak():
    """No integrator was recorded, so none can leak: the candidate is left out and the report says why;
    the same recordings with their integrator's flux keep it."""
    from hystbench.analysis.diagnosis import diagnose

    sense, integrator = [], []
    for f in (80.0, 160.0):
        sim = SimulatedRig("ecore_pm", frequency_hz=f, seed=7)
        block = sim.record(0.1)
        integrator.append(Recording(None, sim.fs_hz, dict(block.channels), sim.metadata()))
        sense.append(with_flux(Recording(None, sim.fs_hz, {k: v for k, v in block.channels.items() if k != "flux_Wb"},
                                         sim.metadata())))
    pool = ["integrator_leak", "force_offset_drift"]
    got = diagnose(sense, candidates=pool, jobs=1)
    assert got.candidates_considered == ["force_offset_drift"]
    assert any("integrated by hystbench from sense_V" in w for w in got.warnings)
    kept = diagnose(integrator, candidates=pool, jobs=1)
    assert kept.candidates_considered == pool and not any("sense_V" in w for w in kept.warnings)
