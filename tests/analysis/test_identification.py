"""Instrument identification from simulated voice-coil sweeps (paper Sec. IV, Figs. 7-9)."""

import functools

import numpy as np
import pytest

from hystbench.analysis.identification import eddy_lag, fit_instrument, frequency_response
from hystbench.reports.paper import simulate_voice_coil_sweep
from hystbench.config import load_rig
from hystbench.errors import EstimationError
from hystbench.physics import presets

FREQS = np.round(np.geomspace(10.0, 45000.0, 40), 2)


@functools.cache
def response(rig):
    return frequency_response(simulate_voice_coil_sweep(rig, FREQS, seed=7))


@functools.cache
def ferrite_fit():
    return fit_instrument(response("voicecoil_ferrite"))


def test_ferrite_sweep_recovers_the_presets_instrument():
    fit = ferrite_fit()
    truth = presets.instrument(load_rig("voicecoil_ferrite"))
    p, s = fit.params, fit.std
    # stated tolerances; each also within 4 of its own standard errors
    for key, true, rel in (("fn_Hz", truth.fn_hz, 0.005), ("zeta_n", truth.zeta_n, 0.15),
                           ("f0_Hz", truth.f0_hz, 0.05), ("zeta_0", truth.zeta_0, 0.05),
                           ("force_constant_N_per_A", 4.0, 0.01)):
        assert p[key] == pytest.approx(true, rel=rel), key
        assert abs(p[key] - true) < 4 * s[key], key
    assert -fit.phase_deg(320.0) == pytest.approx(1.282, abs=0.05)  # the paper's "about 1.28 deg"
    assert fit.phase_std_deg(320.0) < 0.05


def test_ferrite_is_clean_and_ndfeb_shows_eddy_currents_in_its_magnet():
    ref = ferrite_fit().model
    clean = eddy_lag(response("voicecoil_ferrite"), ref, "ferrite")
    assert not clean.significant and abs(clean.lag_deg) < 2.0
    nd = eddy_lag(response("voicecoil_ndfeb"), ref, "ferrite")
    assert nd.significant
    assert nd.lag_deg == pytest.approx(15.0, abs=2.0)  # paper Fig. 7c: about 15 deg at 3 kHz
    assert "eddy currents in the magnet" in nd.verdict


def test_fitting_the_ndfeb_itself_absorbs_its_eddy_lag_into_the_filters():
    own = fit_instrument(response("voicecoil_ndfeb"))
    assert own.params["f0_Hz"] < 0.6 * 31000.0  # why the paper benchmarks on the ferrite coil


def test_sweep_without_the_resonance_is_refused():
    recs = simulate_voice_coil_sweep("voicecoil_ferrite", np.geomspace(10, 1000, 10), seed=1)
    with pytest.raises(EstimationError, match="no resonance peak"):
        fit_instrument(frequency_response(recs))


def test_ecore_recordings_are_not_a_voice_coil_sweep():
    from hystbench.reports.paper import simulate_ecore

    recs = simulate_ecore("ecore_pm", [(320.0, 1.4)], duration_s=0.02)
    with pytest.raises(EstimationError, match="not a voice coil"):
        frequency_response(recs)


def test_points_too_near_nyquist_are_left_out_and_reported():
    from hystbench.formats.recording import Recording
    from hystbench.sim_backend.rig import SimulatedRig

    recs = simulate_voice_coil_sweep("voicecoil_ferrite", [100.0, 1000.0], seed=2)
    sim = SimulatedRig("voicecoil_ferrite", fs_hz=100_000.0, frequency_hz=20_000.0, current_pp_a=1.0)
    recs.append(Recording(None, sim.fs_hz, dict(sim.record(0.01).channels), sim.metadata()))
    with pytest.raises(EstimationError, match="5.0 samples per period"):
        frequency_response(recs)
    dropped = []
    resp = frequency_response(recs, dropped=dropped)
    assert resp.frequency_hz.size == 2 and len(dropped) == 1 and "20000 Hz" in dropped[0][0]


def test_read_sweeps_splits_a_bench_day_folder_by_rig(tmp_path):
    """recording-format.md: one folder may hold a bench day's rigs; identify takes each rig as a sweep
    (named by the rig, or ``<folder>/<rig>`` under a folder of sweeps); a one-rig folder keeps its name."""
    from hystbench.analysis.identification import read_sweeps
    from hystbench.formats.recording import Recording, write_sweep

    def rec(rig, f):
        t = np.arange(100) / 10_000.0
        return Recording(None, 10_000.0, {"current_A": np.sin(2 * np.pi * f * t), "force_N": t},
                         {"rig": rig, "frequency_Hz": f, "sample_rate_Hz": 10_000.0, "current_pp_A": 1.0})

    write_sweep([rec("ecore", 320.0), rec("voicecoil_ferrite", 40.0), rec("ecore", 80.0)], tmp_path / "day" / "mon")
    write_sweep([rec("ecore_pm", 80.0), rec("ecore_pm", 40.0)], tmp_path / "day" / "pm")
    day = read_sweeps(tmp_path / "day" / "mon")
    assert list(day) == ["ecore", "voicecoil_ferrite"]
    assert [r.frequency_hz for r in day["ecore"]] == [80.0, 320.0]
    assert list(read_sweeps(tmp_path / "day")) == ["mon/ecore", "mon/voicecoil_ferrite", "pm"]
    assert [r.frequency_hz for r in read_sweeps(tmp_path / "day" / "pm")["pm"]] == [40.0, 80.0]
    # a loose recording beside the sweep folders: those were skipped without a word, now it is refused
    write_sweep([rec("ecore_pm", 320.0)], tmp_path / "day", names=["loose"])
    from hystbench.errors import RecordingError
    with pytest.raises(RecordingError, match=r"day: holds recordings and sweep folders \(mon, pm\); give the sweep"):
        read_sweeps(tmp_path / "day")
