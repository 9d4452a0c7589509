"""The method's commands end to end: estimate, identify and paper (on a reduced grid)."""

import json

import numpy as np
import pytest

from hystbench.cli.main import main as run  # the hystbench command: BenchError -> exit 2
from hystbench.reports.paper import PAPER, simulate_ecore, simulate_voice_coil_sweep
from hystbench.formats.recording import write_recording, write_sweep

pytestmark = pytest.mark.slow(15)  # ~15 s: handed to a worker before lighter files (tests/conftest.py)


@pytest.fixture(scope="module")
def ecore_stem(tmp_path_factory):
    rec = simulate_ecore("ecore_pm", [(320.0, 1.4)], duration_s=0.05)[0]
    stem = tmp_path_factory.mktemp("rec") / "ecore_pm_320Hz"
    write_recording(rec, stem)
    return stem


def test_estimate_json(ecore_stem, capsys):
    assert run(["estimate", str(ecore_stem) + ".csv", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["frequency_Hz"] == pytest.approx(320.008, abs=1e-3)
    for key in ("hysteresis", "instrument", "total"):
        assert out["delays_s"][key] > 0 and out["delays_std_s"][key] > 0
        assert key in out["phases_deg"] and key in out["covariance_method"]["delays_s"]


def test_estimate_table(ecore_stem, capsys):
    assert run(["estimate", str(ecore_stem)]) == 0
    out = capsys.readouterr().out
    assert "hysteresis" in out and "flux behind" in out and "Eq. 3" in out and "theta_hyst" in out


def test_estimate_reads_an_mcap_log_as_its_csv_export(tmp_path, capsys):
    log = tmp_path / "run.mcap"
    assert run(["record", "--out", str(log), "--seconds", "0.4", "--source", "sim", "--pace", "max"]) == 0
    capsys.readouterr()
    assert run(["estimate", str(log), "--json"]) == 0
    from_log = json.loads(capsys.readouterr().out)
    assert run(["export", str(log), "--out", str(tmp_path / "csv")]) == 0
    capsys.readouterr()
    (stem,) = sorted((tmp_path / "csv").glob("*.csv"))
    assert run(["estimate", str(stem), "--json"]) == 0
    from_csv = json.loads(capsys.readouterr().out)
    for name in ("hysteresis", "instrument", "total"):
        assert from_log["delays_s"][name] == pytest.approx(from_csv["delays_s"][name], rel=1e-12, abs=1e-15)
    assert from_log["frequency_Hz"] == pytest.approx(from_csv["frequency_Hz"], rel=1e-12)


def test_estimate_refuses_missing_logs_and_bad_recordings(tmp_path, ecore_stem, capsys):
    assert run(["estimate", str(tmp_path / "log.mcap")]) == 2
    assert "log.mcap" in capsys.readouterr().err
    lines = (ecore_stem.with_suffix(".csv")).read_text().splitlines()
    bad = tmp_path / "bad"
    (tmp_path / "bad.json").write_text(ecore_stem.with_suffix(".json").read_text())
    (tmp_path / "bad.csv").write_text("\n".join(lines[:5] + [lines[5].replace(lines[5].split(",")[2], "nan", 1)]
                                                + lines[6:]) + "\n")
    assert run(["estimate", str(bad)]) == 2
    assert "bad.csv:6" in capsys.readouterr().err


@pytest.fixture(scope="module")
def coil_sweeps(tmp_path_factory):
    root = tmp_path_factory.mktemp("coils")
    freqs = np.round(np.geomspace(10.0, 45000.0, 20), 2)
    for rig in ("voicecoil_ferrite", "voicecoil_ndfeb"):
        write_sweep(simulate_voice_coil_sweep(rig, freqs), root / rig)
    return root


def test_identify_voice_coil_sweep(coil_sweeps, capsys):
    assert run(["identify", str(coil_sweeps / "voicecoil_ferrite"), "--json"]) == 0
    rep = json.loads(capsys.readouterr().out)
    assert rep["kind"] == "instrument" and rep["eddy_lag_flag"] is False
    assert rep["parameters"]["fn_Hz"] == pytest.approx(4450, rel=0.01)
    assert set(rep["std"]) >= {"fn_Hz", "zeta_n", "f0_Hz", "zeta_0"}
    assert rep["phase_at_320Hz_deg"] == pytest.approx(-1.28, abs=0.1)


def test_identify_folder_of_sweeps_benchmarks_on_the_ferrite(coil_sweeps, capsys):
    assert run(["identify", str(coil_sweeps), "--json"]) == 0
    reps = json.loads(capsys.readouterr().out)["sweeps"]
    assert reps["voicecoil_ferrite"]["benchmark"] and not reps["voicecoil_ndfeb"]["benchmark"]
    assert reps["voicecoil_ndfeb"]["eddy_lag_flag"] is True
    assert "voicecoil_ferrite" in reps["voicecoil_ndfeb"]["reference"]
    assert run(["identify", str(coil_sweeps)]) == 0
    assert "eddy currents in the magnet" in capsys.readouterr().out


def test_identify_ecore_sweep(tmp_path, capsys):
    recs = simulate_ecore("ecore_pm", [(80.0, 1.4), (320.0, 1.4), (320.0, 0.5)], duration_s=0.05)
    write_sweep(recs, tmp_path / "pm")
    again = simulate_ecore("ecore_pm", [(320.0, 1.4)], duration_s=0.05, seed=7)  # one point played twice
    write_sweep(again, tmp_path / "pm", names=["repeat"])
    assert run(["identify", str(tmp_path / "pm"), "--json"]) == 0
    rep = json.loads(capsys.readouterr().out)
    assert rep["kind"] == "hysteresis" and len(rep["points"]) == 4
    by_amp = rep["theta_hyst_deg_by_amplitude"]
    assert set(by_amp) == {"1.4", "0.5"} and len(by_amp["1.4"]["320"]) == 2  # the repeat kept, not replaced
    assert sorted(by_amp["1.4"]["320"]) == sorted(p["theta_hyst_deg"] for p in rep["points"]
                                                  if (p["frequency_Hz"], p["current_pp_A"]) == (320.0, 1.4))
    assert all(p["theta_hyst_deg"] > 0 for p in rep["points"])
    assert run(["identify", str(tmp_path / "pm")]) == 0
    assert "theta_hyst" in capsys.readouterr().out


def test_paper_quick_prints_the_papers_values_beside_ours(tmp_path, capsys):
    assert run(["paper", "--quick", "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    for value in ("4450", "0.012", "1.52", "about 15", "98.5", "98.7", "99.4", "99.7", "2.5", "1.23", "0.63"):
        assert value in out, value
    summary = json.loads((tmp_path / "paper.json").read_text())
    rows = {r["quantity"]: r for r in summary["comparison"]}
    acc = rows["magnet: accuracy of Eq. 6 (phase-delay model) at 320 Hz (%)"]
    assert acc["paper"] == f"{PAPER['accuracy_eq6_pct']['ecore_pm']:g}" and float(acc["hystbench"]) > 50
    assert summary["eddy"]["voicecoil_ndfeb"]["significant"] and not summary["eddy"]["voicecoil_ferrite"]["significant"]
    names = {p.split("/")[-1] for p in summary["figures"]}
    assert {"fig07_bode.png", "fig17_force_error_vs_f.png", "fig18_instrument_phase.png",
            "fig19_hyst_comp.png"} <= names
    assert all((tmp_path / n).stat().st_size > 10_000 for n in names)
