"""Write one concealed bench day of the independent bench, for a diagnosis to be tried on it:

    cd tests && python -m independent_bench CASE OUT_DIR

writes the day into ``OUT_DIR/day`` (every rig in one folder, as a bench day's sweep is) and the
generator's secret into ``OUT_DIR/truth.json``, beside the day, never in it; prints the baseline the
diagnosis is to be told of.  ``make demo`` diagnoses the ``integrator_leak`` day this way.
Like the rest of the package, it imports nothing from ``hystbench``.
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
from pathlib import Path

from .bench import BenchConstants
from .concealed import CASES, Case, write_case


def catalogue_terms(case: Case) -> dict[str, dict[str, float]]:
    """The hidden circuit in the catalogue's words where they differ from this bench's: the integrator's
    leak as one time constant (its feedback resistor and the op-amp's finite gain, in parallel)."""
    out = {}
    leak = case.expected.get("integrator_leak")
    if leak:
        b = case.bench or BenchConstants()
        rate = 1 / (leak["r_feedback_ohm"] * b.integrator_c_f) + 1 / (leak["dc_gain"] * b.integrator_r_in_ohm * b.integrator_c_f)
        out["integrator_leak"] = {"time_constant_s": round(1 / rate, 4)}
    return out


def main(argv: list[str] | None = None) -> int:
    cases = {c.name: c for c in CASES}
    p = argparse.ArgumentParser(prog="python -m independent_bench", description=__doc__.split("\n")[0])
    p.add_argument("case", choices=sorted(cases), metavar="CASE", help=f"one of: {', '.join(cases)}")
    p.add_argument("out", type=Path, help="folder for day/ and truth.json (day/ is replaced)")
    args = p.parse_args(argv)
    case = cases[args.case]
    day = args.out / "day"
    if day.exists():
        shutil.rmtree(day)
    write_case(case, day)
    truth = {"case": case.name, "truth": list(case.truth), "expected": case.expected, "catalogue": catalogue_terms(case),
             "concealment": case.concealment, "baseline": list(case.baseline)}
    (args.out / "truth.json").write_text(json.dumps(truth, indent=2, default=str) + "\n")
    n = len(list(day.glob("*.csv")))
    print(f"independent bench: day {case.name!r}, {n} recordings in {day} (its truth in {args.out / 'truth.json'}); "
          f"diagnose with --baseline {','.join(case.baseline)}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
