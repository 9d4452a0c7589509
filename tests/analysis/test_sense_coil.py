"""A raw sense-coil voltage integrated into the flux: against closed forms, against the simulated
rig's own flux, and through the commands a bench engineer runs on such a recording."""

import json
import re
from dataclasses import replace as dataclasses_replace
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
    err = est - phi  # AC only: the offset did not ramp it (a constant is the convention's, not an error)
    assert np.max(np.abs(err - err.mean())) < 2e-4 * 2e-4  # the end samples' correction, at the 7th


@pytest.mark.parametrize("f,periods", [(333.0, 2.0), (320.0, 3.5), (40.0 * (1 + 40e-6), 48.0)])
def test_an_offset_drifting_along_the_record_leaves_no_trend_in_the_flux(f, periods):
    """An ADC offset that drifts linearly (10 mV over the record, 4 % of the voltage's amplitude) on a
    record that is not a whole number of periods (333 Hz on 100 kHz; a clock 40 ppm off): the flux
    comes back sample by sample, its two harmonics with it (a plain mean left 1.3e-2 of a ramp at two
    periods of 333 Hz)."""
    fs, turns = 100e3, 10
    t = np.arange(int(periods * fs / f)) / fs
    w = 2 * np.pi * f
    phi = 1e-4 * np.sin(w * t) + 2e-5 * np.sin(3 * w * t + 1.0)
    v = -turns * (1e-4 * w * np.cos(w * t) + 6e-5 * w * np.cos(3 * w * t + 1.0)) + 0.02 + 0.01 * t / t[-1]
    err = integrate_sense_voltage(v, fs, turns, float(round(f))) - phi  # the sidecar's nominal
    assert np.max(np.abs(err - err.mean())) < 1e-3 * 1e-4


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
    with pytest.raises(RecordingError, match=rf"^{re.escape(str(tmp_path / 'r'))}\.json: .*{why}"):
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


def test_a_diagnosis_of_integrated_sense_voltages_does_not_look_for_an_integrators_leak():
    """No integrator was recorded, so none can leak: the candidate is left out and the report says why;
    the same recordings with their integrator's flux keep it."""
    from hystbench.analysis.diagnosis import diagnose

    sense, integrator = [], []
    for f in (80.0, 160.0):
        sim = SimulatedRig("ecore_pm", frequency_hz=f, seed=7)
        block = sim.record(0.1)
        integrator.append(Recording(None, sim.fs_hz, dict(block.channels), sim.metadata()))
        sense.append(Recording(None, sim.fs_hz, {k: v for k, v in block.channels.items() if k != "flux_Wb"},
                               sim.metadata()))
    pool = ["integrator_leak", "force_offset_drift"]
    got = diagnose(sense, candidates=pool, jobs=1)
    assert got.candidates_considered == ["force_offset_drift"]
    assert any("integrated by hystbench from sense_V" in w for w in got.warnings)
    kept = diagnose(integrator, candidates=pool, jobs=1)
    assert kept.candidates_considered == pool and not any("sense_V" in w for w in kept.warnings)


def _sense_only(rec: Recording, **meta) -> Recording:
    return Recording(None, rec.fs_hz, {k: v for k, v in rec.channels.items() if k != "flux_Wb"},
                     {**rec.metadata, **meta})


def _simulated(f: float = 160.0, seconds: float = 0.2, seed: int = 5) -> Recording:
    sim = SimulatedRig("ecore_pm", frequency_hz=f, seed=seed)
    return Recording(None, sim.fs_hz, dict(sim.record(seconds).channels), sim.metadata())


def test_a_glitch_in_the_sense_voltage_is_bridged_and_named_not_integrated_into_a_step(tmp_path, capsys):
    """One sample of sense_V at three times the channel's range would be a step in the integral, which
    no later outlier search finds (the hysteresis delay went from 17.88 to 19.04 us, nothing reported):
    it is bridged before the integral, ``estimate`` names it among the outliers, and the command says
    it was bridged (not left out, as a glitch of a channel fitted directly is)."""
    from hystbench.analysis.method import estimate

    rec = _sense_only(_simulated())
    clean = estimate(rec)
    v = rec.channels["sense_V"].copy()
    v[7000] += 3 * np.ptp(v)
    glitched = dataclasses_replace(rec, channels={**rec.channels, "sense_V": v})
    got = estimate(glitched)
    assert got["outliers"]["sense_V"] == [7000] and got["outliers_excluded"]
    for k in ("hysteresis", "instrument"):
        assert abs(got["delays_s"][k] - clean["delays_s"][k]) < 2 * clean["delays_std_s"][k], k
    write_recording(glitched, tmp_path / "glitch")
    assert cli_main(["estimate", str(tmp_path / "glitch"), "--json"]) == 0
    err = capsys.readouterr().err
    assert "bridged by straight lines before the sense voltage was integrated" in err and "sense_V at 7000 (1)" in err
    assert "left out as outliers" not in err


def test_a_sense_coil_wired_the_other_way_is_refused_not_read_as_half_a_period_of_lag():
    rec = _sense_only(_simulated())
    flipped = dataclasses_replace(rec, channels={**rec.channels, "sense_V": -rec.channels["sense_V"]})
    with pytest.raises(RecordingError, match="wired the other way round.*negate the sense_V column"):
        with_flux(flipped)


def test_a_record_shorter_than_two_periods_is_refused():
    rec = _sense_only(_simulated(f=40.0, seconds=0.045))
    with pytest.raises(RecordingError, match=r"1\.80 periods of 40 Hz; integrating it into a flux needs at least two"):
        with_flux(rec)


def test_the_library_entry_points_integrate_a_sense_coil_recording(tmp_path):
    """The method's delays, a force model's period data, identification's sweep reader and the
    diagnosis each take a sense-only recording as they take the integrator's, through one integral."""
    from hystbench.analysis.identification import read_sweeps
    from hystbench.analysis.method import measure_delays
    from hystbench.compensator.sweeps import period_data

    rec = _simulated()
    sense = _sense_only(rec)
    a, b = measure_delays(rec), measure_delays(sense)
    assert abs(a.delays_s["hysteresis"] - b.delays_s["hysteresis"]) < 4 * np.hypot(a.delays_std_s["hysteresis"],
                                                                                  b.delays_std_s["hysteresis"])
    pa, pb = period_data(rec), period_data(sense)
    diff = pa.flux_wb - pb.flux_wb  # AC only: an integrator's DC is where it was reset
    assert np.max(np.abs(diff - diff.mean())) < 2e-3 * np.ptp(pa.flux_wb)
    (tmp_path / "pm").mkdir()
    write_recording(sense, tmp_path / "pm" / "pm_160Hz")
    (got,) = read_sweeps(tmp_path / "pm")["pm"]
    np.testing.assert_allclose(got.channels["flux_Wb"], with_flux(sense).channels["flux_Wb"], rtol=0, atol=1e-15)


def test_a_diagnosis_without_the_turns_goes_on_without_a_flux_and_says_why():
    """The diagnosis can still compare force with current: it warns instead of refusing the day."""
    from hystbench.analysis.diagnosis import diagnose

    recs = []
    for f in (80.0, 160.0):
        r = _sense_only(_simulated(f=f, seconds=0.1, seed=7))
        meta = {k: v for k, v in r.metadata.items() if k != "sense_turns"}
        recs.append(Recording(None, r.fs_hz, r.channels, meta))
    got = diagnose(recs, candidates=["force_offset_drift"], jobs=1)
    assert any("have sense_V but no sense_turns" in w for w in got.warnings)
    assert any("no recording has flux_Wb" in w for w in got.warnings)


def test_a_flat_sense_voltage_and_a_log_segment_are_named_as_what_they_are(tmp_path):
    """A flat voltage is refused as sense_V (not as the flat flux it would make), and a segment of an
    MCAP log is named by the log and its operating point (its sidecar is a record inside the log)."""
    rec = _sense_only(_simulated(seconds=0.05))
    flat = dataclasses_replace(rec, channels={**rec.channels, "sense_V": np.full(rec.n, 0.25)})
    with pytest.raises(RecordingError, match=r"sense_V is flat \(every sample 0\.25\)"):
        with_flux(flat)
    logged = dataclasses_replace(rec, path=tmp_path / "day3.mcap",
                                 metadata={k: v for k, v in rec.metadata.items() if k != "sense_turns"})
    with pytest.raises(RecordingError, match=rf"^{re.escape(str(tmp_path / 'day3.mcap'))}: the ecore_pm recording "
                                             r"at 160 Hz: .*add 'sense_turns'"):
        with_flux(logged)
