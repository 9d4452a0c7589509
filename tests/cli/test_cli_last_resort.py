"""main's last resort catches what remains legitimately possible once every user error is a
BenchError: an OSError from the filesystem, reported as ``PATH: reason``.  A ValueError is a bug
by now and keeps its traceback (a last resort that swallowed it would hide the bug behind a line
that names no option and no file)."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

import hystbench.cli.main as cli_main
from hystbench.cli.main import main


def test_a_path_the_filesystem_refuses_is_one_line_naming_it(tmp_path: Path, capsys) -> None:
    """A file name longer than the filesystem's limit (NAME_MAX) ends in exit 2 and one line that
    starts with the path, as every other message names its file; nothing is written."""
    name_max = os.pathconf(tmp_path, "PC_NAME_MAX")
    stem = tmp_path / ("s" * (name_max + 1))
    code = main(["simulate", "--rig", "ecore", "--freq", "320", "--ipp", "1", "--duration", "0.01",
                 "--out", str(stem)])
    err = capsys.readouterr().err
    assert code == 2
    assert err == f"hystbench simulate: error: {stem}.csv: File name too long\n", err
    assert list(tmp_path.iterdir()) == []
    # in a folder the command makes for it: the folder does not stay behind, empty
    code = main(["simulate", "--rig", "ecore", "--freq", "320", "--ipp", "1", "--duration", "0.01",
                 "--out", str(tmp_path / "new" / "deeper" / stem.name)])
    assert code == 2 and "File name too long" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []


def test_a_value_error_is_a_bug_not_a_user_error(monkeypatch) -> None:
    """A command that ends in a bare ValueError is not dressed up as a user's mistake (exit 2 with
    a line naming nothing): it propagates with its traceback."""
    def broken(args) -> int:
        return int("not a number")  # a bug: nothing the user gave is wrong

    monkeypatch.setattr(cli_main, "cmd_rigs", broken)  # build_parser reads it when main runs
    with pytest.raises(ValueError, match="invalid literal for int"):
        main(["rigs"])
