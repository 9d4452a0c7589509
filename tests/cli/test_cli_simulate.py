"""The simulate commands end to end: files a reader (the recording module) accepts, and clear
errors with exit status 2 for bad input."""

import json

import numpy as np
import pytest

from hystbench.cli.main import main
from hystbench.formats.recording import read_recording, read_sweep


def test_simulate_writes_a_readable_recording(tmp_path, capsys):
    stem = tmp_path / "run"
    assert main(["simulate", "--rig", "ecore_pm", "--freq", "320", "--ipp", "1.4", "--duration", "0.05",
                 "--effect", "mains_pickup=on", "--out", str(stem)]) == 0
    rec = read_recording(stem)
    assert rec.rig == "ecore_pm" and rec.frequency_hz == 320.0 and rec.current_pp_a == 1.4
    assert rec.n == 5000 and set(rec.channels) == {"current_A", "force_N", "flux_Wb", "sense_V", "command_V"}
    assert "mains_pickup" in rec.metadata["effects"]
    i = rec.channels["current_A"]
    assert np.ptp(i) == pytest.approx(1.4, rel=0.01)


def test_simulate_sweep_writes_one_recording_per_point(tmp_path):
    out = tmp_path / "sweep"
    assert main(["simulate-sweep", "--rig", "ecore", "--freqs", "40,320", "--ipp", "1.27", "--duration", "0.05",
                 "--out", str(out)]) == 0
    recs = read_sweep(out)
    assert [r.frequency_hz for r in recs] == [40.0, 320.0]
    assert all(r.rig == "ecore" for r in recs)


def test_refuses_to_overwrite_unless_asked(tmp_path, capsys):
    stem = tmp_path / "run"
    args = ["simulate", "--rig", "voicecoil_ferrite", "--freq", "100", "--ipp", "1", "--duration", "0.02",
            "--out", str(stem)]
    assert main(args) == 0
    assert main(args) == 2 and "exist" in capsys.readouterr().err
    assert main(args + ["--overwrite"]) == 0


@pytest.mark.parametrize("args, words", [
    (["--rig", "nope"], "unknown rig 'nope'"),
    (["--effect", "bogus=on"], "unknown effect 'bogus'"),
    (["--freq", "70000"], "fs/2"),
])
def test_bad_input_is_a_clear_error(tmp_path, capsys, args, words):
    base = ["simulate", "--freq", "320", "--ipp", "1", "--duration", "0.01", "--out", str(tmp_path / "x")]
    assert main(base + args) == 2
    assert words in capsys.readouterr().err


def test_rigs_json_lists_every_preset(capsys):
    assert main(["rigs", "--json"]) == 0
    rows = {r["rig"]: r for r in json.loads(capsys.readouterr().out)}
    assert set(rows) == {"ecore", "ecore_pm", "toroid", "voicecoil_ferrite", "voicecoil_ndfeb", "voicecoil_smco"}
