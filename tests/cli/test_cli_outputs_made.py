"""Outputs a new user asked for: ``simulate --out new/run`` makes its folder (as ``simulate-sweep``
does); ``force-map`` to a format whose tool is missing is one line, not a traceback, and writes nothing."""

from __future__ import annotations

import shutil

import pytest

from hystbench.cli.main import main


def test_simulate_makes_the_folder_of_its_output(tmp_path, capsys):
    out = tmp_path / "new" / "deeper" / "run"
    assert main(["simulate", "--rig", "ecore_pm", "--freq", "320", "--ipp", "1.4", "--duration", "0.05", "--out", str(out)]) == 0
    assert (out.parent / "run.csv").exists() and (out.parent / "run.json").exists()


@pytest.mark.skipif(shutil.which("xelatex") is not None, reason="xelatex is installed: .pgf can be written")
def test_a_format_whose_tool_is_missing_is_one_line_and_writes_nothing(tmp_path, capsys):
    out = tmp_path / "map.pgf"
    assert main(["force-map", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "xelatex" in err and "--out" in err and "Traceback" not in err
    assert list(tmp_path.iterdir()) == []
