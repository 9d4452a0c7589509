"""``make demo``'s last step: a diagnosis of a bench day with a concealed effect (issues 13 and 27).

By default the issue-13 bench day of our simulated rigs whose charge amplifier leaks
(``charge_amp_highpass``, left out of the presets, so out of the diagnosis's baseline) is written as
sweep folders and diagnosed.  ``make demo`` hands it a day written by the independent bench instead
(``tests/independent_bench``, nothing shared with ``sim_backend``: a real bench's physics is never our
simulator's), with the baseline the analyst would give; the generator's truth, kept beside the day in
a file the diagnosis never reads, is printed after the verdict.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Sequence

from ..analysis.diagnosis import diagnose
from ..errors import ConfigError
from ..formats.recording import read_sweep, write_sweep
from ..sim_backend.bench_day import BenchDayPlan
from ..sim_backend.concealed import CASES, simulate_case
from .diagnosis import print_summary, write_report

__all__ = ["demo_diagnosis", "DEMO_CASE", "truth_line"]

#: The concealed case of our simulator the demo diagnoses without a day of its own (the suite's whole
#: day: a short day of two frequencies per rig cannot prove an effect on held-out frequencies).
DEMO_CASE = "charge_amp_highpass"


def demo_diagnosis(out: str | Path, console: Any, day: str | Path | None = None,
                   baseline: Sequence[str] | None = None, truth: str | Path | None = None) -> Path:
    """Diagnose a bench day and report it under ``out`` (``out/report``); returns the report page.

    ``day``: a bench day's folder (every rig in it) to diagnose with ``baseline``, and ``truth`` the
    generator's JSON (``truth``, ``expected``) to print after the verdict; without ``day``,
    :data:`DEMO_CASE`'s day of our simulator is written to ``out/day/RIG`` and diagnosed."""
    out = Path(out)
    if day is None:
        case = next(c for c in CASES if c.name == DEMO_CASE)
        plan = BenchDayPlan()
        recs = simulate_case(case, plan=plan)
        folders = []
        for rig in plan.rigs:
            folders.append(out / "day" / rig)
            write_sweep([r for r in recs if r.rig == rig], folders[-1], overwrite=True)
        told = f"{DEMO_CASE} left out of the presets"
        secret = f"{', '.join(case.truth)} {dict(case.expected[DEMO_CASE])}"
    else:
        recs, folders = read_sweep(day), [Path(day)]
        told = "written by the independent bench (tests/independent_bench), something hidden"
        secret = truth_line(Path(truth)) if truth is not None else "not given"
    console.rule(f"diagnosis: a bench day {told} ({len(recs)} recordings, "
                 f"{', '.join(dict.fromkeys(r.rig for r in recs))})")
    d = diagnose(recs, baseline=list(baseline) if baseline is not None else None)
    page = write_report(d, out / "report", overwrite=True)
    print_summary(d, console)
    console.print(f"truth (never shown to the diagnosis): {secret}; report: {page}")
    option = f" --baseline {','.join(baseline)}" if baseline is not None else ""
    console.print(f"again by hand: hystbench diagnose {' '.join(str(f) for f in folders)}{option} --report DIR")
    return page


def truth_line(path: str | Path) -> str:
    """The generator's truth file as one line: the hidden effects and their parameters."""
    try:
        t = json.loads(Path(path).read_text())
        said = t.get("catalogue") or t.get("expected", {})
        return f"{', '.join(t['truth']) or 'none'} {said} ({t.get('concealment', '')})"
    except (OSError, ValueError, KeyError, TypeError) as e:
        raise ConfigError(f"--truth {path}: not a truth file of the independent bench ({e})") from e
