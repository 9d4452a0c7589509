"""``make demo`` ends with a diagnosis of a concealed bench day (issue 13): the short day names the
effect the generator hid, and the report page and its figures are written."""

from __future__ import annotations

import io

from rich.console import Console

from hystbench.reports.demo_diagnosis import DEMO_CASE, demo_diagnosis


def test_the_demo_names_the_concealed_effect_and_writes_its_report(tmp_path):
    buf = io.StringIO()
    page = demo_diagnosis(tmp_path / "diagnosis", Console(file=buf, width=160))
    out = buf.getvalue()
    assert page == tmp_path / "diagnosis" / "report" / "README.md"
    first = page.read_text().split("\n\n")[1]
    assert f"**{DEMO_CASE}**" in first  # the verdict names the generator's truth
    assert (page.parent / "loops.png").exists() and (page.parent / "heat_map.png").exists()
    assert f"{DEMO_CASE}.time_constant_s = " in out and str(page) in out
    assert sorted(p.name for p in (tmp_path / "diagnosis" / "day").iterdir()) == ["ecore", "ecore_pm",
                                                                                 "voicecoil_ferrite"]
