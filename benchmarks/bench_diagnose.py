"""Benchmark of ``hystbench diagnose`` on the concealed-effect suite (issue 13's targets).

Every case of :data:`hystbench.sim_backend.concealed.CASES` is a bench day (the voice coil's stepped
sine, ``ecore`` at 1.27 A-pp, ``ecore_pm`` at 0.7 and 1.4 A-pp, 40-480 Hz, 48 periods, the presets'
noise) with physics the baseline leaves out, concealed; null cases leave nothing out (other seeds,
presets off nominal, foreign benches).  The diagnosis sees the recordings and the baseline, never the
truth; this benchmark compares its answer with the truth.

Targets: >= 90 % of effect cases named right (top 1), every null case "none", held-out improvement
>= 5x where an effect is present, < 60 s per bench day (the diagnosis's own CPU time, one process: one core;
cases run side by side, one per core).

Run: ``hystbench bench diagnose [--json] [--cases NAME,...] [--out DIR] [--quick]`` (``--out``: each
case's report page and figures, and results.json; ``--quick``: a short day, for a first look only).
"""

from __future__ import annotations

import argparse
import json
import math
import multiprocessing
import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path
from typing import Any, Callable

from hystbench.analysis.diagnosis import diagnose
from hystbench.sim_backend.bench_day import BenchDayPlan
from hystbench.sim_backend.concealed import CASES, Case, simulate_case

TARGETS = {"named_right_pct": 90.0, "improvement_x": 5.0, "seconds_per_sweep": 60.0}


def run_named(name: str, plan: BenchDayPlan | None = None, out: Path | None = None) -> dict[str, Any]:
    """:func:`run_case` of the case called ``name`` (what a worker process is sent: a case's tables
    are read-only mappings, which do not pickle)."""
    return run_case({c.name: c for c in CASES}[name], plan, out)


def run_case(case: Case, plan: BenchDayPlan | None = None, out: Path | None = None,
             say: Callable[[str], None] | None = None) -> dict[str, Any]:
    """Simulate one case's day, diagnose it as an analyst would (its baseline, every candidate), and
    judge the answer against the truth."""
    t0 = time.process_time()
    recs = simulate_case(case, plan=plan)
    t_sim = time.process_time() - t0
    t0 = time.process_time()
    d = diagnose(recs, baseline=list(case.baseline) if case.baseline is not None else None, progress=say, jobs=1)
    t_diag = time.process_time() - t0
    row = {
        "case": case.name, "truth": list(case.truth), "bench": case.bench, "seed": case.seed,
        "concealment": case.concealment, "named": list(d.effects), "effect": d.effect,
        "right": (d.effect is None) if case.null else (d.effect in case.truth),
        "all_found": set(d.effects) == set(case.truth),
        "improvement": d.improvement if math.isfinite(d.improvement) else None,
        "residual_before": d.residual_before, "residual_after": d.residual_after,
        "parameters": {e: {p: {"value": v, "std": s} for p, (v, s) in ps.items()} for e, ps in d.parameters.items()},
        "expected": {e: dict(ps) for e, ps in case.expected.items()},
        "recordings": len(recs), "seconds_simulate": t_sim, "seconds_diagnose": t_diag,
    }
    if out is not None:
        from hystbench.reports.diagnosis import write_report

        row["report"] = str(write_report(d, out / case.name, overwrite=True))
    return row


def targets(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    effect = [r for r in rows if r["truth"]]
    null = [r for r in rows if not r["truth"]]
    out = []
    if effect:
        pct = 100.0 * sum(r["right"] for r in effect) / len(effect)
        out.append({"target": f">= {TARGETS['named_right_pct']:g} % of effect cases named right (top 1)",
                    "measured": f"{pct:.0f} % ({sum(r['right'] for r in effect)}/{len(effect)})",
                    "pass": pct >= TARGETS["named_right_pct"]})
        imps = [r["improvement"] for r in effect]
        worst = min((i for i in imps if i is not None), default=None)
        ok = all(i is not None and i >= TARGETS["improvement_x"] for i in imps)
        out.append({"target": f"held-out improvement >= {TARGETS['improvement_x']:g}x where an effect is present",
                    "measured": "n/a" if worst is None else f"worst {worst:.2f}x "
                                f"({sum(i is not None and i >= TARGETS['improvement_x'] for i in imps)}/{len(imps)})",
                    "pass": ok})
    if null:
        out.append({"target": "every null case: none", "measured": f"{sum(r['right'] for r in null)}/{len(null)}",
                    "pass": all(r["right"] for r in null)})
    if rows:
        slowest = max(r["seconds_diagnose"] for r in rows)
        out.append({"target": f"< {TARGETS['seconds_per_sweep']:g} s per sweep (diagnosis, one core)",
                    "measured": f"slowest {slowest:.1f} s, median "
                                f"{sorted(r['seconds_diagnose'] for r in rows)[len(rows) // 2]:.1f} s",
                    "pass": slowest < TARGETS["seconds_per_sweep"]})
    return out


def confusion(rows: list[dict[str, Any]]) -> dict[str, dict[str, int]]:
    """truth (effects joined by +, or none) -> named -> count."""
    out: dict[str, dict[str, int]] = {}
    for r in rows:
        t = "+".join(r["truth"]) or "none"
        n = "+".join(r["named"]) or "none"
        out.setdefault(t, {}).setdefault(n, 0)
        out[t][n] += 1
    return out


def _print(res: dict[str, Any]) -> None:
    from rich.table import Table

    from hystbench.reports.console import console

    con = console()
    conf = res["confusion"]
    named = sorted({n for row in conf.values() for n in row}, key=lambda n: (n == "none", n))
    t = Table(title="confusion: truth (rows) x named (columns), cases")
    t.add_column("truth \\ named")
    for n in named:
        t.add_column(n, justify="right")
    for truth in sorted(conf, key=lambda n: (n == "none", n)):
        t.add_row(truth, *(str(conf[truth].get(n, "")) for n in named))
    con.print(t)
    t = Table(title="per case: named, held-out residual (noise floors), time")
    for col in ("case", "truth", "named", "right", "before", "after", "improvement", "diagnose (s)"):
        numeric = col in ("before", "after", "improvement", "diagnose (s)")
        t.add_column(col, justify="right" if numeric else "left", no_wrap=not numeric)
    for r in res["cases"]:
        imp = r["improvement"]
        t.add_row(r["case"], "+".join(r["truth"]) or "none", "+".join(r["named"]) or "none",
                  "yes" if r["right"] else "NO", f"{r['residual_before']:.3g}", f"{r['residual_after']:.3g}",
                  "n/a" if imp is None else f"{imp:.1f}x", f"{r['seconds_diagnose']:.1f}")
    con.print(t)
    t = Table(title="targets")
    for col in ("target", "measured", "pass"):
        t.add_column(col)
    for row in res["targets"]:
        t.add_row(row["target"], row["measured"], "PASS" if row["pass"] else "FAIL")
    con.print(t)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="hystbench bench diagnose", description=__doc__.split("\n\n")[0])
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--cases", help="comma-separated case names (default: the whole suite)")
    ap.add_argument("--out", help="folder for each case's report and results.json")
    ap.add_argument("--quick", action="store_true", help="a short bench day (BenchDayPlan.quick): a first look only")
    ap.add_argument("--jobs", type=int, default=0, help="cases diagnosed at once, one core each (default: one per core)")
    args = ap.parse_args(argv)
    by_name = {c.name: c for c in CASES}
    if args.cases:
        names = [n.strip() for n in args.cases.split(",") if n.strip()]
        odd = [n for n in names if n not in by_name]
        if odd or not names:
            ap.error(f"--cases: unknown case {odd[0] if odd else args.cases!r}; known: {', '.join(by_name)}")
        cases = [by_name[n] for n in names]
    else:
        cases = list(CASES)
    plan = BenchDayPlan.quick() if args.quick else None
    out = Path(args.out) if args.out else None
    from hystbench.reports.console import progress

    t0 = time.monotonic()
    jobs = args.jobs or os.cpu_count() or 1
    with progress() as bar:
        task = bar.add_task(f"concealed suite ({jobs} at once)", total=len(cases))
        if jobs == 1:
            rows = []
            for c in cases:
                rows.append(run_case(c, plan, out, say=lambda msg, c=c: bar.update(task, description=f"{c.name}: {msg}")))
                bar.advance(task)
        else:  # one case per process, each diagnosis on one core (its seconds are that core's)
            with ProcessPoolExecutor(jobs, mp_context=multiprocessing.get_context("forkserver")) as pool:
                futures = [pool.submit(run_named, c.name, plan, out) for c in cases]
                for fut in as_completed(futures):
                    bar.advance(task)
                rows = [f.result() for f in futures]
    res = {"cases": rows, "confusion": confusion(rows), "targets": targets(rows), "quick": bool(args.quick),
           "seconds": time.monotonic() - t0}
    if out is not None:
        out.mkdir(parents=True, exist_ok=True)
        (out / "results.json").write_text(json.dumps(res, indent=2, default=float))
    if args.json:
        print(json.dumps(res, indent=2, default=float))
    else:
        _print(res)
        print(f"{len(rows)} cases in {res['seconds']:.0f} s" + (f"; reports in {out}" if out else ""))
    return 0


if __name__ == "__main__":
    sys.exit(main())
