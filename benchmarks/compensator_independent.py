"""``python -m benchmarks compensator``'s independent family (issue 29): every description of the force on
benches written by the independent bench (``tests/independent_bench/family.py``: elliptic loops and
Bouc-Wen's pointed ones, with and without the magnet; nothing shared with hystbench), each fitted as
a user would (the voice coil's sweep for the instrument, the identification sweep from the nominal
preset) and judged on 40-480 Hz recordings the fit never saw: is ``best`` the best of them?"""

from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path
from types import ModuleType
from typing import Any

#: The repository's tests/ folder: the independent bench is the package ``independent_bench`` in it.
TESTS = Path(__file__).resolve().parents[1] / "tests"
#: How far below the best description ``best`` may fall on a recording, and the accuracy it must
#: reach where some description does (issue 29's targets), percentage points and %.
SHORTFALL_PTS, ACCURACY_PCT = 0.01, 99.9


def independent_bench(module: str) -> ModuleType:
    """``independent_bench.MODULE``, imported from the repository's tests/ folder (it is no part of the
    installed hystbench, and imports nothing from it)."""
    import importlib

    if str(TESTS) not in sys.path:
        sys.path.append(str(TESTS))
    return importlib.import_module(f"independent_bench.{module}")


def judge_bench(name: str, folder: Path) -> dict[str, Any]:
    """One bench of the family: written, identified, fitted, every description judged."""
    from hystbench.analysis.identification import fit_instrument, frequency_response
    from hystbench.compensator import fit_models, force_error
    from hystbench.compensator.calibration import calibrate
    from hystbench.compensator.choice import fit_descriptions
    from hystbench.compensator.hysteresis_eddy import IronScaling
    from hystbench.compensator.sweeps import period_data, sweep_data
    from hystbench.config import load_rig
    from hystbench.formats.recording import read_sweep
    from hystbench.physics import presets

    sweeps = independent_bench("family").write_family_bench(name, folder)
    t = time.monotonic()
    instrument = fit_instrument(frequency_response(read_sweep(sweeps["voicecoil"]))).model
    rig, points = sweep_data(read_sweep(sweeps["fit"]))
    preset = load_rig(rig)
    models = fit_models(points, preset, instrument)
    fit_s = time.monotonic() - t
    magnet = "magnet" in preset
    every = fit_descriptions(points, calibrate(points, instrument, magnet), IronScaling.from_mec(presets.ecore_mec(preset)),
                             instrument, magnet)
    judged = []
    for rec in read_sweep(sweeps["judge"]):
        p = period_data(rec)
        acc = {d: force_error(m, p, instrument)["accuracy_pct"] for d, m in every.items() if not isinstance(m, Exception)}
        best = force_error(models["best"], p, instrument)["accuracy_pct"]
        judged.append({"frequency_Hz": rec.frequency_hz, "current_pp_A": rec.current_pp_a, "descriptions": acc,
                       "best": best, "shortfall_pts": max(acc.values()) - best})
    choice = models.report["choice"]
    return {"bench": name, "chosen": choice["chosen"], "why": choice["why"], "fit_seconds": fit_s,
            "held_out_worst_pct": choice["worst_held_out_accuracy_pct"], "judge": judged,
            "failed": {d: str(m) for d, m in every.items() if isinstance(m, Exception)}}


def independent_family() -> list[dict[str, Any]]:
    from rich.progress import Progress

    names = independent_bench("family").FAMILY
    out = []
    with Progress(transient=True) as bar, tempfile.TemporaryDirectory() as tmp:
        task = bar.add_task("independent benches", total=len(names))
        for name in names:
            out.append(judge_bench(name, Path(tmp) / name.replace("~", "_")))
            bar.advance(task)
    return out


def independent_targets(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    out = []
    for r in rows:
        worst = max(j["shortfall_pts"] for j in r["judge"])
        # no choice of one description can do better than the one whose largest shortfall is smallest
        bound = min(max(max(j["descriptions"].values()) - j["descriptions"][d] for j in r["judge"])
                    for d in r["judge"][0]["descriptions"])
        out.append({"target": f"{r['bench']} (independent): best within {SHORTFALL_PTS} points of the best description "
                              "on every unseen recording",
                    "measured": f"largest shortfall {worst:.3f} points ({r['chosen']}); the least any one description "
                                f"reaches: {bound:.3f}", "pass": worst <= SHORTFALL_PTS})
        reach = max(min(j["descriptions"][d] for j in r["judge"]) for d in r["judge"][0]["descriptions"])
        best = min(j["best"] for j in r["judge"])
        out.append({"target": f"{r['bench']} (independent): best >= {ACCURACY_PCT} % worst case where a description "
                              "reaches it",
                    "measured": f"best {best:.3f} %, the best description's worst case {reach:.3f} %",
                    "pass": None if reach < ACCURACY_PCT else best >= ACCURACY_PCT})
    return out


def print_independent(rows: list[dict[str, Any]], console: Any) -> None:
    from rich.table import Table

    for r in rows:
        names = list(r["judge"][0]["descriptions"])
        t = Table(title=f"{r['bench']} (independent bench): accuracy (%) on recordings the fit did not see; "
                        f"best = {r['chosen']}")
        for col in ("f (Hz)", "A-pp", *names, "best", "shortfall (points)"):
            t.add_column(col, justify="right")
        for j in r["judge"]:
            top = max(j["descriptions"].values())
            t.add_row(f"{j['frequency_Hz']:g}", f"{j['current_pp_A']:g}",
                      *(("[bold]" if j["descriptions"][d] == top else "") + f"{j['descriptions'][d]:.3f}" for d in names),
                      f"{j['best']:.3f}", f"{j['shortfall_pts']:.3f}")
        console.print(t)
        console.print(f"  chosen: {r['why']}" + (f"; failed: {r['failed']}" if r["failed"] else ""))
