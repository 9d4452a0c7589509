"""Benchmark: does a bench day's decision limit (``hystbench.analysis.diagnosis.limits``) say what the day
decides?

For a catalogue effect, one parameter at a time: the null day's limit, then the same day (its seed, so
its noise) with the effect at 0.5x and 2x that size (a time constant or a stiffness, whose size is its
inverse, at 2x and 0.5x of the limit), each diagnosed as an analyst would.  The limit is where the
expected score a^2 q - k ln n reaches the naming margin (T = 10 + k ln n, about 17 for one parameter), so
at 2x the effect's first-round score should be near 4 T - k ln n (about 62), decisive, and at 0.5x near
T/4 - k ln n (about -3), not; the day's own noise moves both.  Measured: the effect's first-round score at
each size, whether it was named and, when not, why.  On our simulator's null day and on the independent
bench's (for the parameters it names as we do: the skews, the charge amplifier's time constant).

Run: ``python -m benchmarks limits [--jobs N] [--json F] [--markdown F]`` (about 4 minutes on two cores).
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import os
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

from benchmarks.bench_diagnose import independent_suite, run_case, run_independent_case, suite_cases
from hystbench.analysis.diagnosis.result import Limit

#: (effect, parameter) swept on our simulator's null day.
OURS = (("channel_skew", "current_A"), ("channel_skew", "flux_Wb"), ("charge_amp_highpass", "time_constant_s"),
        ("integrator_leak", "time_constant_s"), ("force_offset_drift", "drift_n_per_s"),
        ("magnet_thermal_drift", "kelvin_per_s"), ("iron_thermal_drift", "kelvin_per_s"),
        ("load_cell_compliance", "stiffness_n_per_m"), ("amplifier_distortion", "second"),
        ("excess_loss", "coefficient_a_per_m_per_sqrt_t_per_s"))
#: The independent bench's name for the same parameter, in the same unit.
INDEPENDENT = {("channel_skew", "current_A"): ("channel_skew", "current_A"),
               ("channel_skew", "flux_Wb"): ("channel_skew", "flux_Wb"),
               ("charge_amp_highpass", "time_constant_s"): ("charge_amp_highpass", "tau_s")}
#: The effect's other sizes, off, while one is swept (our catalogue's names).
OTHERS_OFF = {"channel_skew": {"current_A": 0.0, "force_N": 0.0, "flux_Wb": 0.0, "sense_V": 0.0, "command_V": 0.0},
              "force_offset_drift": {"offset_n": 0.0, "drift_n_per_s": 0.0},
              "amplifier_distortion": {"second": 0.0, "third": 0.0}}
#: Below and above the limit, as a share of its size.
FACTORS = (0.5, 2.0)
NULL = {"ours": "null_seed1", "independent": "null_seed1"}


def day(suite: str, effect: str | None = None, param: str | None = None, value: float = 0.0) -> dict[str, Any]:
    """The suite's null day, or the same day with ``effect``'s ``param`` at ``value``: its diagnosis's row."""
    null = {c.name: c for c in suite_cases(suite)}[NULL[suite]]
    if effect is None:
        return run_case(null) if suite == "ours" else run_independent_case(null)
    if suite == "ours":
        from hystbench.sim_backend.concealed import make_case

        params = {**OTHERS_OFF.get(effect, {}), param: value}
        case = make_case(f"{effect}.{param}={value:.3g}", [effect], {effect: params}, seed=null.seed,
                         concealment="a limit's sweep")
        return run_case(case)
    name, theirs = INDEPENDENT[(effect, param)]
    others = {k: 0.0 for k in ("current_A", "force_N", "flux_Wb", "command_V") if k != theirs} if name == "channel_skew" else {}
    case = independent_suite().case_hiding(f"{effect}.{param}={value:.3g}", {name: {theirs: value, **others}},
                                           seed=null.seed)
    return run_independent_case(case)


def sweeps(null_rows: dict[str, dict[str, Any]]) -> list[tuple[str, str, str, float, float]]:
    """(suite, effect, param, factor, value) of each day to diagnose: the limits the null days gave,
    in range, at each factor of their size."""
    out = []
    for suite, row in null_rows.items():
        chosen = OURS if suite == "ours" else tuple(INDEPENDENT)
        for effect, param in chosen:
            lim = row["limits"].get(effect, {}).get(param)
            if lim is None or not lim["in_range"] or lim["value"] is None:
                continue
            for factor in FACTORS:
                value = lim["value"] / factor if lim["at_most"] else lim["value"] * factor
                out.append((suite, effect, param, factor, value))
    return out


def _run(job: tuple[str, str, str, float, float]) -> dict[str, Any]:
    suite, effect, param, _, value = job
    return day(suite, effect, param, value)


def verdicts(todo: list[tuple[str, str, str, float, float]], rows: list[dict[str, Any]],
             nulls: dict[str, dict[str, Any]]) -> list[dict[str, Any]]:
    """Each swept day's verdict: the effect's first-round score (None: not scored), decisive or not, named."""
    from hystbench.analysis.diagnosis.select import NAME_MARGIN

    out = []
    for (suite, effect, param, factor, value), row in zip(todo, rows):
        score = row["first_scores"].get(effect)
        out.append({"suite": suite, "effect": effect, "param": param, "factor": factor, "value": value,
                    "limit": nulls[suite]["limits"][effect][param], "score": score,
                    "decided": None if score is None else score >= NAME_MARGIN,
                    "named": effect in row["named"], "all_named": row["named"], "why": row["why"]})
    return out


def summary(table: list[dict[str, Any]]) -> dict[str, str]:
    """Decisive above the limit, undecided below it, named at each side (a day whose effect was not
    scored at all is counted apart, never as undecided)."""
    lo, hi = min(FACTORS), max(FACTORS)
    above = [r for r in table if r["factor"] == hi]
    below = [r for r in table if r["factor"] == lo]
    return {f"decisive at {hi:g}x": f"{sum(r['decided'] is True for r in above)}/{len(above)}",
            f"undecided at {lo:g}x": f"{sum(r['decided'] is False for r in below)}/{len(below)}",
            f"named at {hi:g}x": f"{sum(r['named'] for r in above)}/{len(above)}",
            f"named at {lo:g}x": f"{sum(r['named'] for r in below)}/{len(below)}",
            "not scored": str(sum(r["decided"] is None for r in table))}


def markdown(table: list[dict[str, Any]], summ: dict[str, str]) -> str:
    lo, hi = min(FACTORS), max(FACTORS)
    lines = [f"| bench | effect parameter | limit | score at {lo:g}x | score at {hi:g}x | named at {lo:g}x / {hi:g}x |",
             "|---|---|---|---|---|---|"]
    for key in dict.fromkeys((r["suite"], r["effect"], r["param"]) for r in table):
        mine = {r["factor"]: r for r in table if (r["suite"], r["effect"], r["param"]) == key}
        bound = Limit(key[1], key[2], **{**mine[hi]["limit"], "note": ""}).bound()
        lines.append(f"| {key[0]} | {key[1]} {key[2]} | {bound} | {_score(mine.get(lo))} | {_score(mine.get(hi))} | "
                     f"{_yes(mine.get(lo))} / {_yes(mine.get(hi))} |")
    return "\n".join(lines + ["", " ".join(f"{k}: {v}." for k, v in summ.items())])


def main(argv: list[str] | None = None) -> int:
    from hystbench.reports.console import progress

    ap = argparse.ArgumentParser(prog="python -m benchmarks limits", description=__doc__.split("\n\n")[0])
    ap.add_argument("--jobs", type=int, default=0, help="days diagnosed at once (default: one per core)")
    ap.add_argument("--json", help="write the results to this file")
    ap.add_argument("--markdown", help="write the table docs/diagnosis.md shows to this file")
    args = ap.parse_args(argv)
    jobs = args.jobs or os.cpu_count() or 1
    t0 = time.monotonic()
    with progress() as bar, ProcessPoolExecutor(jobs, mp_context=multiprocessing.get_context("forkserver")) as pool:
        task = bar.add_task("null days", total=len(NULL))
        nulls = dict(zip(NULL, pool.map(day, NULL)))
        bar.update(task, completed=len(NULL))
        todo = sweeps(nulls)
        task = bar.add_task(f"each limit at {' and '.join(f'{f:g}x' for f in FACTORS)} ({jobs} at once)", total=len(todo))
        rows = []
        for row in pool.map(_run, todo):
            rows.append(row)
            bar.advance(task)
    table = verdicts(todo, rows, nulls)
    summ = {**summary(table), "seconds": str(round(time.monotonic() - t0))}
    text = markdown(table, summ)
    print(text)
    if args.json:
        Path(args.json).write_text(json.dumps({"rows": table, "summary": summ,
                                               "null_limits": {s: r["limits"] for s, r in nulls.items()}},
                                              indent=1, default=str))
    if args.markdown:
        Path(args.markdown).write_text(text + "\n")
    return 0


def _score(r: dict[str, Any] | None) -> str:
    if r is None or r["score"] is None:
        return "-"
    return f"{r['score']:.1f}" + (" (decisive)" if r["decided"] else "")


def _yes(r: dict[str, Any] | None) -> str:
    return "-" if r is None else ("yes" if r["named"] else "no")
