"""Learning through the emulated instruments' drivers: time per iteration over many iterations.

``hystbench compensate --learn`` (``BenchActuation`` on the emulated bench) used to slow from 0.2 s
to 10 s per iteration until the bench timed out after ~5 iterations (issue 10, item 3): the
streams' backlog grew with every iteration.  Target: constant time per iteration; the mean of the
last ten iterations within 1.5x the mean of iterations 1-10 (iteration 0 has the first settling),
and the samples dropped per new table (what arrived while the learning computed) not growing.

Each iteration reads ``max(0.05, 4/f)`` s to settle and ``--measure`` s to measure (0.3 s of
samples at 320 Hz with the default 0.25 s), so at real time an iteration cannot take less.
Run: ``python -m benchmarks learning_bench [--iterations 100] [--measure 0.25] [--json]``.
"""

from __future__ import annotations

import argparse
import json
import time
from contextlib import ExitStack

import numpy as np

from hystbench.compensator import BenchActuation, ForceReference, LearningConfig, run_closed_loop
from hystbench.compensator.sweeps import quick_models
from hystbench.drivers.bench import Bench
from hystbench.drivers.protocols.bench_config import load_bench_config
from hystbench.sim_backend.emulators.bench import EmulatedBench

REFERENCE = "offset=170,amp=40,freq=320"
TARGET_GROWTH = 1.5


def run(iterations: int = 100, measure_s: float = 0.25) -> dict:
    ref = ForceReference.parse(REFERENCE)
    models = quick_models("ecore_pm", seed=1000)
    config = load_bench_config()
    rows: list[dict] = []
    with ExitStack() as stack:
        emu = stack.enter_context(EmulatedBench(config))
        bench = stack.enter_context(Bench(config.resolved(emu.addresses)))
        act = BenchActuation(bench, config.current_limit_a)
        last = [time.perf_counter(), 0]

        def on_iteration(rep) -> None:
            now = time.perf_counter()
            rows.append({"iteration": rep.iteration, "wall_s": now - last[0], "ratio": rep.ratio,
                         "dropped_samples": bench.discarded_samples - last[1],
                         "emulator_slipped_s": emu.pacer.slipped_s if emu.pacer else 0.0})
            last[0], last[1] = now, bench.discarded_samples

        t0 = time.perf_counter()
        run_closed_loop(act, models["best"], ref, models.instrument, learn=True,
                        config=LearningConfig(iterations=iterations - 1), measure_s=measure_s,
                        on_iteration=on_iteration)
        act.output_off()
        total = time.perf_counter() - t0
    wall = np.array([r["wall_s"] for r in rows])
    first, tail = wall[1:11].mean(), wall[-10:].mean()
    return {"reference": REFERENCE, "iterations": len(rows), "measure_s": measure_s, "total_s": total,
            "wall_s_first_10": float(first), "wall_s_last_10": float(tail), "wall_s_max": float(wall.max()),
            "growth": float(tail / first), "passed": bool(tail <= TARGET_GROWTH * first), "rows": rows}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks learning_bench", description=__doc__.split("\n")[0])
    parser.add_argument("--iterations", type=int, default=100)
    parser.add_argument("--measure", type=float, default=0.25, help="seconds averaged per iteration")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args(argv)
    result = run(args.iterations, args.measure)
    if args.json:
        print(json.dumps(result, indent=2))
        return 0
    rows = result["rows"]
    for r in rows[:3] + rows[-3:]:
        print(f"iteration {r['iteration']:3d}: {r['wall_s']:.3f} s, dropped {r['dropped_samples']} samples")
    verdict = "meets" if result["passed"] else "MISSES"
    print(f"{result['iterations']} iterations in {result['total_s']:.1f} s: {result['wall_s_first_10']:.3f} s per "
          f"iteration (1-10), {result['wall_s_last_10']:.3f} s (last 10), max {result['wall_s_max']:.3f} s; growth "
          f"{result['growth']:.2f}x {verdict} the {TARGET_GROWTH:g}x target")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
