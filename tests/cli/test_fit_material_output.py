"""`hystbench fit-material` prints a table a person reads (it printed Python dict reprs), with the
same figures its --json gives."""

from __future__ import annotations

import json

from hystbench.cli.main import main


def test_fit_material_prints_each_loops_errors_as_a_table(tmp_path, capsys):
    assert main(["fit-material", "--out", str(tmp_path / "j"), "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert main(["fit-material", "--out", str(tmp_path / "t")]) == 0
    out = capsys.readouterr().out
    assert "{'" not in out and "rms %" in out
    rows = {line.split("│")[1].strip(): [c.strip() for c in line.split("│")[2:-1]]
            for line in out.splitlines() if line.startswith("│")}
    assert set(rows) == set(result["errors"])
    for loop, e in result["errors"].items():
        assert rows[loop][1:3] == [f"{e['rms_pct']:.2f}", f"{e['max_pct']:.2f}"]
        assert rows[loop][4] == f"{result['baseline_errors'][loop]['rms_pct']:.1f}"
    for name in result["figures"]:
        assert f"figure {name}: {tmp_path / 't'}" in out
