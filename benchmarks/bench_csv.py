"""CSV recording import: peak memory and time of ``read_recording`` and ``hystbench estimate``.

Issue 10: a 10 s recording at 100 kS/s (six columns, ~97 MB of CSV) took 8 s and 730 MB to
estimate, so a 60 s one needed ~4 GB.  This benchmark writes a recording of each duration with the
simulated rig (``hystbench simulate --rig ecore_pm --freq 320 --ipp 1.4 --duration D``), then runs,
each in a fresh Python process:

- ``reader``: ``read_recording(STEM)``;
- ``estimate``: ``hystbench estimate STEM --json`` (reader plus the fit of :mod:`.method`);
- for each, its imports alone: the floor (interpreter, numpy, scipy...) subtracted below.

Each child's peak resident set (``ru_maxrss``) and CPU time come from ``os.wait4``, which gives the
rusage of that one child (``getrusage(RUSAGE_CHILDREN)`` would give the largest of all children so
far).  Per MB of CSV: the peak above the import floor, and wall seconds.  Targets: the reader's
peak above the floor is at most the float64 arrays (8 B x rows x columns) plus ``CHUNK_ALLOWANCE_MIB``;
``estimate``'s (the reader's arrays plus the fits, which go block by block) at most
``ESTIMATE_MIB_PER_MB`` per MB of CSV, about three times the float64 arrays.  With several
durations the CPU time of ``estimate`` is compared with the data's growth (linear: ratio ~1).

"Before" figures: run this file with ``PYTHONPATH`` pointing at an older checkout's folder,
from a working directory outside any checkout (``python -c``/``-m`` put the working directory
first on the path, ahead of ``PYTHONPATH``); the children inherit both.  Give ``--keep`` the same
folder both times to measure the same recordings.  The 60 s case (~580 MB of CSV) takes a few
minutes on one core; pass ``--durations 10 60``.
Run: ``python -m benchmarks csv [--durations 10 60] [--keep DIR] [--json]``.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

DURATIONS = (10.0,)
CHUNK_ALLOWANCE_MIB = 32.0  # the text chunk, its parse and the time check, whatever the file size
#: estimate's peak above its import floor per MB of CSV: the six float64 columns are 0.47 MiB per
#: MB, the fits may add a few arrays of a channel's size, never N x (fitted parameters)
ESTIMATE_MIB_PER_MB = 1.5
SIM_ARGS = ("--rig", "ecore_pm", "--freq", "320", "--ipp", "1.4")
#: What each step imports before it reads anything: its memory floor, whatever the file.
FLOORS = {"reader": "import hystbench.formats.recording",
          "estimate": "import hystbench.cli.main, hystbench.analysis.method, rich.table"}
_MIB = 2.0 ** 20


def _measure(argv: list[str]) -> dict:
    """Run ``argv`` as a child; its wall time, CPU time and peak RSS (MiB).  A failure is raised."""
    started = time.perf_counter()
    proc = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    _, status, usage = os.wait4(proc.pid, 0)  # this child's own rusage
    wall = time.perf_counter() - started
    proc.returncode = os.waitstatus_to_exitcode(status)
    err = proc.stderr.read().decode(errors="replace")
    proc.stderr.close()
    if proc.returncode != 0:
        raise RuntimeError(f"{' '.join(argv)} exited {proc.returncode}: {err.strip()[-500:]}")
    return {"wall_s": wall, "cpu_s": usage.ru_utime + usage.ru_stime, "peak_MiB": usage.ru_maxrss / 1024.0}


def _python(code: str) -> list[str]:
    return [sys.executable, "-c", code]


def _file(stem: Path, suffix: str) -> Path:
    return stem.with_name(stem.name + suffix)  # not with_suffix: the stem holds a '.' (1.4App)


def _recording(folder: Path, duration: float) -> Path:
    """The simulated recording of ``duration`` seconds in ``folder``, written unless already there."""
    stem = folder / f"ecore_pm_320Hz_1.4App_{duration:g}s"
    if not (_file(stem, ".csv").is_file() and _file(stem, ".json").is_file()):
        subprocess.run([sys.executable, "-m", "hystbench", "simulate", *SIM_ARGS, "--duration", f"{duration:g}",
                        "--out", str(stem)], check=True, stdout=subprocess.DEVNULL)
    return stem


def _shape(stem: Path) -> tuple[int, int]:
    """(rows, columns) of the CSV, counted without parsing it."""
    with open(_file(stem, ".csv"), "rb") as fh:
        columns = fh.readline().count(b",") + 1
        rows = sum(block.count(b"\n") for block in iter(lambda: fh.read(1 << 20), b""))
    return rows, columns


def _case(stem: Path, duration: float) -> dict:
    csv_mb = _file(stem, ".csv").stat().st_size / 1e6
    rows, columns = _shape(stem)
    steps = {
        "reader": _measure(_python(f"from hystbench.formats.recording import read_recording; "
                                   f"read_recording({str(stem)!r})")),
        "estimate": _measure([sys.executable, "-m", "hystbench", "estimate", str(stem), "--json"]),
    }
    for step, r in steps.items():
        r["floor_MiB"] = _measure(_python(FLOORS[step]))["peak_MiB"]
        r["above_floor_MiB"] = r["peak_MiB"] - r["floor_MiB"]
        r["MiB_per_MB"] = r["above_floor_MiB"] / csv_mb
        r["s_per_MB"] = r["wall_s"] / csv_mb
        r["cpu_s_per_MB"] = r["cpu_s"] / csv_mb  # steadier than wall time on a shared machine
    arrays = 8.0 * rows * columns / _MIB
    reader_ok = steps["reader"]["above_floor_MiB"] <= arrays + CHUNK_ALLOWANCE_MIB
    estimate_ok = steps["estimate"]["MiB_per_MB"] <= ESTIMATE_MIB_PER_MB
    return {"duration_s": duration, "csv_MB": csv_mb, "rows": rows, "columns": columns,
            "float64_MiB": arrays, **steps,
            "fit_extra_MiB": steps["estimate"]["peak_MiB"] - steps["reader"]["peak_MiB"],
            "reader_passed": reader_ok, "estimate_passed": estimate_ok, "passed": reader_ok and estimate_ok}


def _scaling(cases: list[dict]) -> dict | None:
    """How estimate's CPU time grew from the shortest to the longest recording, against the data."""
    if len(cases) < 2:
        return None
    short, long_ = min(cases, key=lambda c: c["csv_MB"]), max(cases, key=lambda c: c["csv_MB"])
    data, cpu = long_["csv_MB"] / short["csv_MB"], long_["estimate"]["cpu_s"] / short["estimate"]["cpu_s"]
    return {"from_s": short["duration_s"], "to_s": long_["duration_s"], "data_ratio": data,
            "estimate_cpu_ratio": cpu, "estimate_cpu_ratio_per_data_ratio": cpu / data}


def run(durations: tuple[float, ...] = DURATIONS, keep: str | None = None) -> dict:
    """Measure each duration; recordings go to ``keep`` (reused next time) or a temporary folder."""
    with tempfile.TemporaryDirectory(prefix="bench_csv_") as tmp:
        folder = Path(keep) if keep else Path(tmp)
        folder.mkdir(parents=True, exist_ok=True)
        cases = [_case(_recording(folder, d), d) for d in durations]
    return {
        "benchmark": "csv",
        "cases": cases,
        "chunk_allowance_MiB": CHUNK_ALLOWANCE_MIB,
        "estimate_MiB_per_MB_target": ESTIMATE_MIB_PER_MB,
        "estimate_time_scaling": _scaling(cases),
        "passed": all(c["passed"] for c in cases),
        "python": platform.python_version(),
        "numpy": np.__version__,
        "machine": platform.machine(),
    }


def _print_table(result: dict) -> None:
    from hystbench.reports.console import console
    from rich.table import Table

    table = Table(title="CSV import: peak RSS above the import floor, and wall time, per MB of CSV")
    for col in ("recording", "MB CSV", "float64 MiB", "step", "peak MiB", "floor", "above floor", "MiB / MB",
                "wall s", "cpu s", "s / MB"):
        table.add_column(col, justify="right")
    for c in result["cases"]:
        for step in ("reader", "estimate"):
            r = c[step]
            table.add_row(f"{c['duration_s']:g} s", f"{c['csv_MB']:.1f}", f"{c['float64_MiB']:.1f}", step,
                          f"{r['peak_MiB']:.0f}", f"{r['floor_MiB']:.0f}", f"{r['above_floor_MiB']:.0f}",
                          f"{r['MiB_per_MB']:.2f}",
                          f"{r['wall_s']:.2f}", f"{r['cpu_s']:.2f}", f"{r['s_per_MB']:.4f}")
    out = console()
    out.print(table)
    for c in result["cases"]:
        verdict = "meets" if c["reader_passed"] else "MISSES"
        out.print(f"{c['duration_s']:g} s: reader {c['reader']['above_floor_MiB']:.0f} MiB above its "
                  f"{c['reader']['floor_MiB']:.0f} MiB import floor for {c['float64_MiB']:.0f} MiB of float64 "
                  f"({verdict} arrays + {result['chunk_allowance_MiB']:g} MiB); the fit adds "
                  f"{c['fit_extra_MiB']:.0f} MiB")
        e = c["estimate"]
        verdict = "meets" if c["estimate_passed"] else "MISSES"
        out.print(f"{c['duration_s']:g} s: estimate {e['above_floor_MiB']:.0f} MiB above its {e['floor_MiB']:.0f} "
                  f"MiB import floor = {e['MiB_per_MB']:.2f} MiB per MB of CSV ({verdict} <= "
                  f"{result['estimate_MiB_per_MB_target']:g}), {e['wall_s']:.1f} s wall, {e['cpu_s']:.1f} s CPU")
    sc = result["estimate_time_scaling"]
    if sc:
        out.print(f"estimate {sc['from_s']:g} s -> {sc['to_s']:g} s: {sc['data_ratio']:.1f} x the data, "
                  f"{sc['estimate_cpu_ratio']:.1f} x the CPU time ({sc['estimate_cpu_ratio_per_data_ratio']:.2f} "
                  "per unit of data; 1 is linear)")


def main(argv: list[str] | None = None) -> int:
    """Command line: print the table (or JSON with ``--json``); exit 1 if the reader or estimate misses
    its memory target."""
    parser = argparse.ArgumentParser(prog="python -m benchmarks csv", description=__doc__.split("\n")[0])
    parser.add_argument("--durations", type=float, nargs="+", default=list(DURATIONS),
                        help="recording lengths in seconds at 100 kS/s (default 10; 60 takes minutes)")
    parser.add_argument("--keep", metavar="DIR", help="write the recordings here and reuse them next time")
    parser.add_argument("--json", action="store_true", help="print the result as JSON")
    args = parser.parse_args(argv)
    if any(d <= 0 for d in args.durations):
        parser.error(f"--durations must be > 0, got {args.durations}")
    result = run(tuple(args.durations), args.keep)
    if args.json:
        json.dump(result, sys.stdout, indent=2)
        sys.stdout.write("\n")
    else:
        _print_table(result)
    return 0 if result["passed"] else 1


if __name__ == "__main__":
    sys.exit(main())
