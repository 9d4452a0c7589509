"""Issue 30, item 4: an all-or-nothing writer's error names the destination the user gave, never
the hidden temporary it was writing (which is removed and which nobody can find)."""

from __future__ import annotations

import errno
from pathlib import Path

import numpy as np
import pytest

from hystbench.errors import RecordingError
from hystbench.formats.outputs import output_file, output_folder
from hystbench.formats.recording import Recording, write_recording


def test_a_writers_error_in_an_output_file_names_the_destination(tmp_path: Path):
    out = tmp_path / "model.json"
    with pytest.raises(RecordingError) as caught:
        with output_file(out) as tmp:
            raise RecordingError(f"{tmp}: the writer gave up")  # a writer names the path it was handed
    assert str(caught.value) == f"{out}: the writer gave up"
    assert list(tmp_path.iterdir()) == []


def test_a_failed_write_in_an_output_folder_names_the_file_where_it_was_going(tmp_path: Path):
    target = tmp_path / "report"
    with pytest.raises(RecordingError) as caught:
        with output_folder(target) as stage:
            (stage.path / "figures").write_text("a file where the writer wants a folder")
            (stage.path / "figures" / "heat.png").write_bytes(b"png")  # NotADirectoryError
    text = str(caught.value)
    assert str(target / "figures" / "heat.png") in text, text
    assert ".tmp" not in text, text
    assert list(tmp_path.iterdir()) == []


def test_an_input_error_in_an_output_folder_is_left_as_it_came(tmp_path: Path):
    missing = tmp_path / "input.csv"
    with pytest.raises(FileNotFoundError) as caught:
        with output_folder(tmp_path / "report"):
            missing.read_text()
    assert caught.value.errno == errno.ENOENT and caught.value.filename == str(missing)


def test_write_recording_names_the_recording_not_its_temporary(tmp_path: Path):
    fs = 1000.0
    rec = Recording(path=None, fs_hz=fs, channels={"current_A": np.zeros(10)}, t0_s=0.0,
                    metadata={"rig": "ecore_pm", "frequency_Hz": 50.0, "sample_rate_Hz": fs, "current_pp_A": 1.0})
    (tmp_path / "run.csv").mkdir()  # the destination cannot be replaced
    (tmp_path / "run.csv" / "keep").write_text("")
    with pytest.raises(RecordingError) as caught:
        write_recording(rec, tmp_path / "run", overwrite=True)
    text = str(caught.value)
    assert text.startswith(f"{tmp_path / 'run'}: cannot write the recording"), text
    assert ".tmp" not in text, text
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run.csv"]  # no temporary left behind
