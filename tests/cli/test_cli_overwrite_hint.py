"""Issue 30, item 3: the refusal to replace an existing output tells a command-line user the flag
(``--overwrite``), not only the Python keyword."""

from __future__ import annotations

from pathlib import Path

import pytest

from hystbench.cli.main import main
from hystbench.errors import RecordingError
from hystbench.formats.mcaplog import McapRecorder


def refusal(argv: list[str], capsys) -> str:
    code = main(argv)
    lines = [ln for ln in capsys.readouterr().err.splitlines() if ": error: " in ln]
    assert code == 2 and len(lines) == 1
    return lines[0]


def test_record_over_an_existing_log_names_the_flag(tmp_path: Path, capsys):
    out = tmp_path / "run.mcap"
    out.write_bytes(b"kept")
    line = refusal(["record", "--source", "synthetic", "--pace", "max", "--seconds", "0.01", "--out", str(out)],
                   capsys)
    assert str(out) in line and "--overwrite" in line
    assert out.read_bytes() == b"kept"


def test_export_over_existing_recordings_names_the_flag(tmp_path: Path, capsys):
    log = tmp_path / "run.mcap"
    assert main(["record", "--source", "synthetic", "--pace", "max", "--seconds", "0.05", "--out", str(log)]) == 0
    assert main(["export", str(log), "--out", str(tmp_path / "x")]) == 0
    capsys.readouterr()
    line = refusal(["export", str(log), "--out", str(tmp_path / "x")], capsys)
    assert "already exists" in line and "--overwrite" in line


def test_the_library_message_still_names_the_keyword(tmp_path: Path):
    out = tmp_path / "run.mcap"
    out.write_bytes(b"kept")
    with pytest.raises(RecordingError, match="overwrite=True"):
        McapRecorder(out).start()
