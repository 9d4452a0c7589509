"""``make demo``'s last step: a diagnosis of a bench day with a concealed effect (issue 13).

The issue's bench day of the simulated rigs whose charge amplifier leaks (``charge_amp_highpass``, left out
of the presets, so out of the diagnosis's baseline) is written as sweep folders, diagnosed as
``hystbench diagnose`` would, and summarised in a short table with its report page.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from ..analysis.diagnosis import diagnose
from ..formats.recording import write_sweep
from ..sim_backend.bench_day import BenchDayPlan
from ..sim_backend.concealed import CASES, simulate_case
from .diagnosis import print_summary, write_report

__all__ = ["demo_diagnosis", "DEMO_CASE"]

#: The concealed case the demo diagnoses (the suite's whole day: a short day of two frequencies per
#: rig cannot prove an effect on held-out frequencies).
DEMO_CASE = "charge_amp_highpass"


def demo_diagnosis(out: str | Path, console: Any) -> Path:
    """Simulate, write, diagnose and report :data:`DEMO_CASE`'s bench day under ``out``
    (``out/day/RIG`` sweep folders, ``out/report``); returns the report page's path."""
    out = Path(out)
    case = next(c for c in CASES if c.name == DEMO_CASE)
    plan = BenchDayPlan()
    recs = simulate_case(case, plan=plan)
    folders = []
    for rig in plan.rigs:
        folders.append(out / "day" / rig)
        write_sweep([r for r in recs if r.rig == rig], folders[-1], overwrite=True)
    console.rule(f"diagnosis: a bench day whose {DEMO_CASE} the presets leave out "
                 f"({len(recs)} recordings, {', '.join(plan.rigs)})")
    d = diagnose(recs)
    page = write_report(d, out / "report", overwrite=True)
    print_summary(d, console)
    console.print(f"truth (never shown to the diagnosis): {', '.join(case.truth)} "
                  f"{dict(case.expected[DEMO_CASE])}; report: {page}")
    console.print(f"again by hand: hystbench diagnose {' '.join(str(f) for f in folders)} --report DIR")
    return page
