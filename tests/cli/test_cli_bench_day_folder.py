"""A bench day's folder holding several rigs (recording-format.md, issue 27): ``diagnose`` reads every
rig's recordings from it; ``model fit``, which fits one actuator, refuses it naming the folder and its
rigs, before any work.  Small synthetic recordings: only the reading is under test."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from hystbench.cli.diagnose import read_inputs
from hystbench.cli.main import main
from hystbench.errors import RecordingError
from hystbench.formats.recording import Recording, write_sweep

FS = 10_000.0


def _rec(rig: str, freq: float, ipp: float) -> Recording:
    t = np.arange(200) / FS
    i = 0.5 * ipp * np.sin(2 * np.pi * freq * t)
    return Recording(path=None, fs_hz=FS, channels={"current_A": i, "force_N": 2.0 * i},
                     metadata={"rig": rig, "frequency_Hz": freq, "sample_rate_Hz": FS, "current_pp_A": ipp})


@pytest.fixture()
def two_rigs(tmp_path: Path) -> Path:
    """One folder: three ecore_pm points and two ecore points, written interleaved."""
    folder = tmp_path / "day"
    write_sweep([_rec("ecore_pm", 320.0, 1.4), _rec("ecore", 160.0, 1.27), _rec("ecore_pm", 80.0, 1.4),
                 _rec("ecore", 80.0, 1.27), _rec("ecore_pm", 80.0, 0.7)], folder)
    return folder


def test_diagnose_reads_both_rigs_of_one_folder(two_rigs):
    recs = read_inputs([two_rigs])
    assert [(r.rig, r.frequency_hz, r.current_pp_a) for r in recs] == [
        ("ecore", 80.0, 1.27), ("ecore", 160.0, 1.27),
        ("ecore_pm", 80.0, 0.7), ("ecore_pm", 80.0, 1.4), ("ecore_pm", 320.0, 1.4)]


def test_diagnose_reads_a_day_written_one_folder_per_rig(tmp_path):
    """As ``simulate-bench-day`` writes it: DAY/ecore, DAY/ecore_pm; ``diagnose DAY`` takes both."""
    write_sweep([_rec("ecore_pm", 320.0, 1.4), _rec("ecore_pm", 80.0, 1.4)], tmp_path / "day" / "ecore_pm")
    write_sweep([_rec("ecore", 160.0, 1.27), _rec("ecore", 80.0, 1.27)], tmp_path / "day" / "ecore")
    (tmp_path / "day" / "notes").mkdir()  # a folder without recordings is not a rig's
    recs = read_inputs([tmp_path / "day"])
    assert [(r.rig, r.frequency_hz) for r in recs] == [("ecore", 80.0), ("ecore", 160.0), ("ecore_pm", 80.0),
                                                        ("ecore_pm", 320.0)]


def test_an_empty_day_folder_is_still_refused_naming_it(tmp_path):
    (tmp_path / "day" / "notes").mkdir(parents=True)
    with pytest.raises(RecordingError, match="no recordings") as info:
        read_inputs([tmp_path / "day"])
    assert str(tmp_path / "day") in str(info.value)


def test_diagnose_still_refuses_a_folder_of_one_recording(tmp_path):
    write_sweep([_rec("ecore", 80.0, 1.27)], tmp_path / "one")
    with pytest.raises(RecordingError, match="only one recording") as info:
        read_inputs([tmp_path / "one"])
    assert str(tmp_path / "one") in str(info.value)


def test_model_fit_refuses_a_folder_of_several_rigs_naming_it(two_rigs, tmp_path, capsys):
    out = tmp_path / "m.json"
    assert main(["model", "fit", str(two_rigs), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert f"{two_rigs}: recordings of several rigs" in err and "ecore: 2" in err and "ecore_pm: 3" in err
    assert not out.exists()


def test_model_fit_refuses_a_mixed_instrument_sweep_naming_it(two_rigs, tmp_path, capsys):
    one = tmp_path / "pm"
    write_sweep([_rec("ecore_pm", 80.0, 1.4), _rec("ecore_pm", 320.0, 1.4)], one)
    out = tmp_path / "m.json"
    assert main(["model", "fit", str(one), "--out", str(out), "--instrument-sweep", str(two_rigs)]) == 2
    err = capsys.readouterr().err
    assert f"{two_rigs}: recordings of several rigs" in err
    assert not out.exists()
