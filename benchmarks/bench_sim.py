"""Simulated-rig speed: how many times faster than real time it runs at 100 kS/s, on one core.

Target (issue: foundation): >= 20x real time for the E-core with hysteresis and eddy currents on.
Runs each rig preset as configured (every effect its preset turns on: hysteresis, eddy currents,
instrument filter, noise, ADC), timed with wall-clock over whole seconds of signal after a warm-up.
Run: ``hystbench bench sim [--seconds N] [--json]``.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")  # one core, as the target says

import numpy as np  # noqa: E402

from hystbench.sim_backend.rig import SimulatedRig  # noqa: E402

TARGET_REALTIME_FACTOR = 20.0


def run(seconds: float = 5.0, fs_hz: float = 100_000.0, block_size: int = 10_000,
        rigs: tuple[str, ...] = ("ecore_pm", "ecore", "voicecoil_ndfeb")) -> dict:
    results = []
    for name in rigs:
        rig = SimulatedRig(name, fs_hz=fs_hz, seed=1)
        rig.record(0.2, block_size)  # warm caches
        n_blocks = int(round(seconds * fs_hz / block_size))
        wall0, cpu0 = time.perf_counter(), time.process_time()
        for _ in range(n_blocks):
            rig.read(block_size)
        wall, cpu = time.perf_counter() - wall0, time.process_time() - cpu0
        simulated = n_blocks * block_size / fs_hz
        results.append({"rig": name, "effects": sorted(rig.effects), "seconds_simulated": simulated,
                        "wall_s": wall, "cpu_s": cpu, "realtime_factor": simulated / wall})
    head = results[0]
    return {
        "benchmark": "sim",
        "fs_hz": fs_hz,
        "block_size": block_size,
        "rig": head["rig"],
        "realtime_factor": head["realtime_factor"],
        "target_realtime_factor": TARGET_REALTIME_FACTOR,
        "passed": head["realtime_factor"] >= TARGET_REALTIME_FACTOR,
        "rigs": results,
        "python": platform.python_version(),
        "numpy": np.__version__,
        "machine": platform.machine(),
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="hystbench bench sim", description=__doc__.split("\n")[0])
    parser.add_argument("--seconds", type=float, default=5.0, help="simulated seconds per rig")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args(argv)
    result = run(args.seconds)
    if args.json:
        print(json.dumps(result, indent=2))
        return 0
    from hystbench.reports.console import console
    from rich.table import Table

    table = Table(title=f"simulated rig at {result['fs_hz']:g} S/s, blocks of {result['block_size']}")
    for col in ("rig", "effects on", "simulated (s)", "wall (s)", "x real time"):
        table.add_column(col)
    for r in result["rigs"]:
        table.add_row(r["rig"], str(len(r["effects"])), f"{r['seconds_simulated']:g}",
                      f"{r['wall_s']:.3f}", f"{r['realtime_factor']:.1f}")
    console().print(table)
    verdict = "meets" if result["passed"] else "MISSES"
    print(f"{result['rig']}: {result['realtime_factor']:.1f}x real time {verdict} the {TARGET_REALTIME_FACTOR:g}x target")
    return 0
