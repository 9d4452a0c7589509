"""``hystbench demo`` never replaces an earlier demo's output unless told to (the README's promise):
it refuses before anything runs; ``make demo`` gives each run a folder of its own."""

from __future__ import annotations

import re
from pathlib import Path

from hystbench.cli.main import main

ROOT = Path(__file__).resolve().parents[2]


def test_an_earlier_demo_is_refused_naming_overwrite_and_left_as_it_was(tmp_path, capsys):
    out = tmp_path / "demo"
    (out / "live").mkdir(parents=True)
    (out / "live" / "old.mcap").write_bytes(b"earlier run")
    assert main(["demo", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "--overwrite" in err and "live" in err and err.count("\n") == 1
    assert sorted(p.name for p in out.rglob("*")) == ["live", "old.mcap"]  # nothing written, nothing removed


def test_make_demo_writes_a_new_folder_each_run():
    recipe = (ROOT / "Makefile").read_text().split("\ndemo:")[1].split("\n\n")[0]
    assert re.search(r"run=demo-output/\$\$\(date \+%Y%m%d-%H%M%S\)", recipe)
    assert "--out $$run " in recipe and "--overwrite" not in recipe
