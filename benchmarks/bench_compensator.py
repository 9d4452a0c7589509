"""Benchmark of the force models and the compensator on the simulated rig (issue 6 targets).

Per E-core rig (presets as shipped: noise at the paper's level, 0.0015 N rms without magnet,
0.03 N with):

1. fit every model on an identification sweep (40, 160, 480 Hz x 0.3, 0.7, 1.1, 1.5 A-pp, seed
   1000, 8 periods or 0.1 s per recording);
2. judge them on other recordings (seed 5000+, 0.5 s or 80 periods, whichever is longer, so the
   average measures the model more than the noise): 40, 80, 160, 320, 480 Hz at the paper's
   amplitude (1.27 A-pp without magnet, 1.4 with) and at 0.9 A-pp, which the fit did not see.
   Accuracy = 100 % x (1 - max|F_measured - H_instr{F_model(i)}| / force range) on the period
   average (``analysis.periodic.synchronous_average`` at the method's true frequency);
3. at 320 Hz: Eq. 6's error reduction over Eq. 1 three ways -- through the instrument's whole
   response (as everything here), with the paper's phase-only instrument correction
   (``analysis.force_error``), and the best any phase-delay model could do on that very
   recording (delay and k0, k1, k2 fitted to it: an upper bound for Eq. 6);
4. closed loop from rest with learning, 10 iterations: the tracking error against the noise
   floor of the same averaged record; for the magnet rig also after the paper's 1.4 A-pp
   excitation (the iron's memory) and for a multi-sine.

5. the same on every foreign bench (``sim_backend.benches``: geometry, turns, magnet and airgap off
   by up to 20 %, another iron, the instrument off its nominal values): the instrument identified
   with the ferrite voice coil on the bench's load cell, the models fitted from the nominal preset
   (all a user of that bench has), judged at 40-480 Hz, Eq. 6 at 320 Hz, learning from rest.

6. every description of the force (Eq. 1, Eq. 6 and the iron descriptions) on the independent
   bench's family (:mod:`benchmarks.compensator_independent`: elliptic and Bouc-Wen iron, with and
   without the magnet, code that shares nothing with hystbench): is ``best`` the best of them?

Run: ``python -m benchmarks compensator [--json] [--out DIR] [--quick] [--family] [--independent]`` (figures
in DIR; ``--family`` only the foreign benches' table, ``--independent`` only the independent family's).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from hystbench.compensator import (ForceReference, LearningConfig, RigActuation, fit_models, force_error,
                                   run_closed_loop)
from hystbench.compensator.models import phase_delay_bound_n
from hystbench.compensator.sweeps import (FIT_GRID, JUDGE_FREQS_HZ, period_data, quick_instrument, quick_models,
                                          sweep_data)
from hystbench.sim_backend.benches import FOREIGN_BENCHES, foreign_preset
from hystbench.config import load_rig
from hystbench.drivers.protocols.bench_config import load_bench_config
from hystbench.sim_backend.recordings import simulated_sweep
from hystbench.sim_backend.rig import SimulatedRig

from benchmarks.compensator_independent import independent_family, independent_targets, print_independent

MAIN_IPP = {"ecore": 1.27, "ecore_pm": 1.4}
UNSEEN_IPP = 0.9
PAPER_FACTOR = {"ecore": 2.5, "ecore_pm": 5.0}
REFERENCES = {"ecore": "offset=2,amp=1,freq=320", "ecore_pm": "offset=170,amp=40,freq=320"}
MULTISINE = "offset=170,amp=30,freq=160,h2=10@45,h3=5"
TARGETS = {"accuracy_pct": 99.9, "reduction_x": 10.0, "ratio": 2.0, "iterations": 10}


def judge_duration_s(frequency_hz: float) -> float:
    """Length of a judged recording: 0.5 s (the paper grid's) or 80 periods, whichever is longer."""
    return max(0.5, 80.0 / frequency_hz)


def paper_phase_only(rec, models) -> float:
    """Eq. 1 / Eq. 6 max-error ratio with the paper's correction (force shifted by the instrument delay)."""
    from hystbench.analysis.force_error import force_error as fe_paper

    fe = fe_paper(rec, models["paper"].phase)
    return fe.max_abs_n("instrument") / fe.max_abs_n("hysteresis")


def judge(rig: str, models, quick: bool, bench=None) -> tuple[list[dict], dict]:
    """Step 2-3 on ``rig`` (the nominal preset's name), or on ``bench`` (a foreign bench's preset)."""
    rows, extra = [], {}
    freqs = (80.0, 320.0) if quick else JUDGE_FREQS_HZ
    for n, f in enumerate(freqs):
        for ipp in (MAIN_IPP[rig], UNSEEN_IPP):
            rec = simulated_sweep(rig if bench is None else bench, [f], [ipp],
                                  seed=5000 + 10 * n + (ipp == UNSEEN_IPP), duration_s=judge_duration_s(f))[0]
            p = period_data(rec)
            errs = {k: force_error(m, p, models.instrument) for k, m in models.models.items()}
            rows.append({"rig": rig, "frequency_Hz": f, "current_pp_A": ipp, "force_range_N": p.force_range_n,
                         "accuracy_pct": {k: e["accuracy_pct"] for k, e in errs.items()},
                         "max_abs_error_N": {k: e["max_abs_error_N"] for k, e in errs.items()},
                         "averaged_force_noise_N": p.force_noise_rms_n / np.sqrt(p.periods)})
            if f == 320.0 and ipp == MAIN_IPP[rig]:
                eq1, eq6, best = (errs[k]["max_abs_error_N"] for k in ("nonhysteretic", "paper", "best"))
                extra = {"eq6_reduction_x": eq1 / eq6, "eq6_reduction_paper_correction_x": paper_phase_only(rec, models),
                         "eq6_oracle_reduction_x": eq1 / phase_delay_bound_n(p, models.instrument),
                         "best_reduction_x": eq1 / best, "loops": {k: (p.current_a, e["error_N"]) for k, e in errs.items()}}
    return rows, extra


def iron_loops(points, models, magnet: bool) -> list[dict]:
    """The evidence the model was chosen on: per fit recording, the iron's share of the current
    d = i - j against j (j from the flux, ``compensator.calibration``), beside the best model's d."""
    from hystbench.compensator.calibration import calibrate
    from hystbench.compensator.identify import iron_data

    best = models["best"]
    data = iron_data(points, calibrate(points, models.instrument, magnet))
    return [{"f": p.nominal_frequency_hz, "ipp": p.current_pp_a, "j": j, "d": i - j,
             "model": best.current_for(j, p.frequency_hz) - j} for p, j, i in zip(data.points, data.js, data.currents)]


def closed_loop(rig: str, models, spec: str, *, history: bool = False, kind: str = "best", seed: int = 7) -> dict:
    ref = ForceReference.parse(spec)
    kw = {} if history else {"current_pp_a": 0.0}  # history: the preset's own excitation ran before
    limit = load_bench_config().current_limit_a  # the shipped bench's, as `hystbench compensate` takes it
    act = RigActuation(SimulatedRig(rig, seed=seed, frequency_hz=ref.frequency_hz, **kw), limit)
    res = run_closed_loop(act, models[kind], ref, models.instrument, learn=True, config=LearningConfig(iterations=10))
    return {"rig": rig, "reference": ref.description, "model": kind,
            "start": "after 1.4 A-pp (iron memory)" if history else "from rest",
            **res.as_dict()}


def foreign_reference(models, nominal: str) -> str:
    """A force reference inside the bench's own range (its identified law): the nominal's shape,
    centred on the law's force at zero current with the magnet, 2 +- 1 N without."""
    if nominal == "ecore":
        return REFERENCES["ecore"]
    law = models["best"].law
    mid, half = float(law.force(0.0)), 0.5 * float(law.force(0.5) - law.force(-0.5))
    return f"offset={mid:.4g},amp={0.6 * half:.3g},freq=320"


def foreign(name: str, quick: bool) -> dict:
    """Step 5 of the module docstring for one bench."""
    bench = FOREIGN_BENCHES[name]
    preset = foreign_preset(name)
    t = time.monotonic()
    instrument = quick_instrument(preset)
    models = quick_models(bench.nominal, bench=preset, instrument=instrument)
    fit_s = time.monotonic() - t
    rows, extra = judge(bench.nominal, models, quick, bench=preset)
    extra.pop("loops", None)
    ref = foreign_reference(models, bench.nominal)
    act = RigActuation(SimulatedRig(preset, seed=7, frequency_hz=320.0, current_pp_a=0.0),
                       load_bench_config().current_limit_a)
    loop = run_closed_loop(act, models["best"], ForceReference.parse(ref), models.instrument, learn=True,
                           config=LearningConfig(iterations=10)).as_dict()
    ins = models.instrument
    return {"bench": name, "iron": bench.material, "description": preset["description"], "fit_seconds": fit_s,
            "instrument_identified": {"fn_Hz": ins.fn_hz, "zeta_n": ins.zeta_n},
            "instrument_true": {"fn_Hz": preset["instrument"]["fn_hz"], "zeta_n": preset["instrument"]["zeta_n"]},
            "chosen": models.report["choice"]["chosen"], "why": models.report["choice"]["why"],
            "judge": rows, **extra, "learning": {"reference": ref, "reached_at": loop["reached_at"],
                                                 "ratios": [r["ratio"] for r in loop["iterations"]]}}


def family(quick: bool = False) -> list[dict]:
    from rich.progress import Progress

    out = []
    with Progress(transient=True) as bar:
        task = bar.add_task("foreign benches", total=len(FOREIGN_BENCHES))
        for name in FOREIGN_BENCHES:
            out.append(foreign(name, quick))
            bar.advance(task)
    return out


def family_targets(rows: list[dict]) -> list[dict]:
    out = []
    for r in rows:
        nominal = FOREIGN_BENCHES[r["bench"]].nominal
        accs = [j["accuracy_pct"]["best"] for j in r["judge"]]
        out.append({"target": f"{r['bench']}: best model >= 99.9 % at 40-480 Hz (unseen)",
                    "measured": f"{min(accs):.3f} % worst, {np.median(accs):.3f} % median ({r['chosen']})",
                    "pass": min(accs) >= TARGETS["accuracy_pct"]})
        if r["bench"].endswith("~elliptic"):
            out.append({"target": f"{r['bench']}: Eq. 6 >= {PAPER_FACTOR[nominal]:g}x at 320 Hz (elliptic loops)",
                        "measured": f"{r['eq6_reduction_x']:.1f}x (bound {r['eq6_oracle_reduction_x']:.1f}x)",
                        "pass": r["eq6_reduction_x"] >= PAPER_FACTOR[nominal]})
        reached = r["learning"]["reached_at"]
        out.append({"target": f"{r['bench']}: learning within 2x the noise floor in <= 10 iterations",
                    "measured": f"reached at {reached}; ratios " + " ".join(f"{x:.1f}" for x in r["learning"]["ratios"]),
                    "pass": reached is not None and reached <= TARGETS["iterations"]})
    return out


def run(quick: bool = False) -> dict:
    out: dict = {"rigs": {}, "closed_loop": []}
    for rig in ("ecore", "ecore_pm"):
        t = time.monotonic()
        _, pts = sweep_data(simulated_sweep(rig, *FIT_GRID, seed=1000))
        models = fit_models(pts, load_rig(rig))
        fit_s = time.monotonic() - t
        rows, extra = judge(rig, models, quick)
        out["rigs"][rig] = {"fit_seconds": fit_s, "fit_recordings": len(pts), "judge": rows, "_iron": iron_loops(pts, models, rig == "ecore_pm"),
                            "best_model": {k: v for k, v in models["best"].to_dict().items() if k != "report"},
                            "chosen": models.report["choice"]["why"],
                            **{k: v for k, v in extra.items() if k != "loops"}, "_loops": extra.get("loops")}
        out["closed_loop"].append(closed_loop(rig, models, REFERENCES[rig]))
        if not quick:
            out["closed_loop"].append(closed_loop(rig, models, REFERENCES[rig], kind="paper"))
            if rig == "ecore_pm":
                out["closed_loop"].append(closed_loop(rig, models, REFERENCES[rig], history=True))
                out["closed_loop"].append(closed_loop(rig, models, MULTISINE))
    out["targets"] = targets(out)
    return out


def targets(res: dict) -> list[dict]:
    rows = []
    for rig, r in res["rigs"].items():
        accs = [j["accuracy_pct"]["best"] for j in r["judge"]]
        rows.append({"target": f"{rig}: best model accuracy >= 99.9 % at 40-480 Hz (unseen recordings)",
                     "measured": f"{min(accs):.3f} % (worst of {len(accs)}), {np.median(accs):.3f} % median",
                     "pass": min(accs) >= TARGETS["accuracy_pct"]})
        rows.append({"target": f"{rig}: best model error >= 10x below non-hysteretic at 320 Hz",
                     "measured": f"{r['best_reduction_x']:.1f}x", "pass": r["best_reduction_x"] >= TARGETS["reduction_x"]})
        # our rigs' iron is a Preisach one, not elliptic: the paper's factor is a target on the benches
        # whose minor loops are elliptic (family below); here the reason and the bound are printed
        rows.append({"target": f"{rig}: paper model (Eq. 6) against the paper's {PAPER_FACTOR[rig]:g}x at 320 Hz "
                               "(n/a: a Preisach iron's loops are not ellipses and change with amplitude; one law "
                               "for the sweep)",
                     "measured": (f"{r['eq6_reduction_x']:.2f}x through the instrument's response; "
                                  f"{r['eq6_reduction_paper_correction_x']:.2f}x with the paper's phase-only correction; "
                                  f"{r['eq6_oracle_reduction_x']:.2f}x for the best phase-delay model fitted to that "
                                  "very recording"),
                     "pass": None})
    for c in res["closed_loop"]:
        if c["model"] == "best" and c["start"] == "from rest":
            reached = c["reached_at"]
            last = c["iterations"][-1]
            rows.append({"target": f"{c['rig']}: learning, {c['reference']}: within 2x the noise floor in <= 10 iterations",
                         "measured": (f"reached at iteration {reached}; last: {last['max_error_n']:.3g} N vs floor "
                                      f"{last['noise_floor_n']:.3g} N ({last['ratio']:.2f}x)"),
                         "pass": reached is not None and reached <= TARGETS["iterations"]})
    return rows


def family_figure(rows: list[dict], folder: Path) -> Path:
    """Per foreign bench: the best model's and Eq. 6's error against frequency (worst of the two
    amplitudes), beside the 99.9 % target."""
    from hystbench.reports.figures import plt, save_figure

    fig, axes = plt.subplots(1, 2, figsize=(13, 4.8), sharey=True)
    for ax, nominal in zip(axes, ("ecore_pm", "ecore")):
        for n, r in enumerate(x for x in rows if FOREIGN_BENCHES[x["bench"]].nominal == nominal):
            freqs = sorted({j["frequency_Hz"] for j in r["judge"]})
            for kind, style in (("best", "-o"), ("paper", ":")):
                worst = [max(100 - j["accuracy_pct"][kind] for j in r["judge"] if j["frequency_Hz"] == f) for f in freqs]
                ax.plot(freqs, worst, style, color=f"C{n}", ms=4,
                        label=f"{r['bench']}: ours ({r['chosen']})" if kind == "best" else f"{r['bench']}: Eq. 6")
        ax.axhline(0.1, color="k", lw=0.8, ls="--", label="target: 99.9 % accuracy")
        ax.set_yscale("log")
        ax.set(title=f"benches off the {nominal} preset: recordings the fit never saw", xlabel="frequency (Hz)",
               ylabel="100 % - accuracy (%), worse of the two amplitudes")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=6)
    return save_figure(fig, folder / "compensator_foreign_benches.png")


def figures(res: dict, folder: Path) -> list[Path]:
    from hystbench.reports.figures import plt, save_figure

    folder.mkdir(parents=True, exist_ok=True)
    paths = []
    if res.get("family"):
        paths.append(family_figure(res["family"], folder))
    if not res.get("rigs"):
        return paths
    colours = {"nonhysteretic": "tab:grey", "paper": "tab:orange", "best": "tab:blue"}
    labels = {"nonhysteretic": "Eq. 1 (non-hysteretic)", "paper": "Eq. 6 (paper)", "best": "ours (best)"}
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.5))
    for ax, (rig, r) in zip(axes, res["rigs"].items()):
        for ipp, style in ((MAIN_IPP[rig], "-o"), (UNSEEN_IPP, "--s")):
            sel = [j for j in r["judge"] if j["current_pp_A"] == ipp]
            f = [j["frequency_Hz"] for j in sel]
            for k in colours:
                ax.plot(f, [100 - j["accuracy_pct"][k] for j in sel], style, color=colours[k], ms=4,
                        label=f"{labels[k]}, {ipp:g} A-pp")
        ax.axhline(0.1, color="k", lw=0.8, ls=":", label="target: 99.9 % accuracy")
        ax.set_yscale("log")
        ax.set(title=f"{rig}: max |dF| / force range, unseen recordings", xlabel="frequency (Hz)",
               ylabel="100 % - accuracy (%)")
        ax.grid(True, which="both", alpha=0.3)
    axes[0].legend(fontsize=7, ncol=2)
    paths.append(save_figure(fig, folder / "compensator_accuracy.png"))

    fig, axes = plt.subplots(1, 2, figsize=(12, 4.5))
    for ax, (rig, r) in zip(axes, res["rigs"].items()):
        for k, (i, e) in (r.get("_loops") or {}).items():
            ax.plot(i, e, color=colours[k], lw=1, label=labels[k])
        ax.set(title=f"{rig}, 320 Hz, {MAIN_IPP[rig]:g} A-pp: F_measured - H_instr{{F_model}}", xlabel="current (A)",
               ylabel="dF (N)")
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=8)
    paths.append(save_figure(fig, folder / "compensator_error_320Hz.png"))

    fig, axes = plt.subplots(2, 2, figsize=(12, 8))
    for row, (rig, r) in zip(axes, res["rigs"].items()):
        for ax, f in zip(row, (40.0, 480.0)):
            for n, loop in enumerate(x for x in r["_iron"] if x["f"] == f):
                ax.plot(loop["j"], 1e3 * loop["d"], color=f"C{n}", lw=1.2, label=f"measured, {loop['ipp']:g} A-pp")
                ax.plot(loop["j"], 1e3 * loop["model"], "k--", lw=0.7, label="ours" if n == 0 else None)
            ax.set(title=f"{rig}, {f:g} Hz: the iron's share of the current", xlabel="j: current the airgaps see (A)",
                   ylabel="d = i - j (mA)")
            ax.grid(True, alpha=0.3)
            ax.legend(fontsize=7)
    paths.append(save_figure(fig, folder / "compensator_iron_loops.png"))

    fig, ax = plt.subplots(figsize=(7.5, 4.5))
    for c in res["closed_loop"]:
        it = [r["iteration"] for r in c["iterations"]]
        ax.semilogy(it, [r["ratio"] for r in c["iterations"]], "-o", ms=3,
                    label=f"{c['rig']}, {c['model']}, {c['reference'][:34]}, {c['start']}")
    ax.axhline(2.0, color="k", ls=":", lw=0.8, label="target: 2x the noise floor")
    ax.axhline(1.0, color="k", lw=0.5)
    ax.set(title="learning: max |dF| of the averaged force / its noise floor", xlabel="iteration (0: feed-forward)",
           ylabel="error / noise floor")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=6)
    paths.append(save_figure(fig, folder / "compensator_learning.png"))
    return paths


def _print_family(rows: list[dict]) -> None:
    from rich.table import Table

    from hystbench.reports.console import console

    con = console()
    t = Table(title="foreign benches: accuracy (%) of the best model on recordings the fit did not see, "
                    "Eq. 6 at 320 Hz, learning")
    for col in ("bench", "iron (chosen)", "worst", "median", "at 480 Hz", "Eq. 6 x (bound)", "learning reached",
                "fn identified / true"):
        t.add_column(col, justify="right")
    for r in rows:
        accs = [j["accuracy_pct"]["best"] for j in r["judge"]]
        at480 = [j["accuracy_pct"]["best"] for j in r["judge"] if j["frequency_Hz"] == 480.0]
        t.add_row(r["bench"], f"{r['iron']} ({r['chosen']})", f"{min(accs):.3f}", f"{np.median(accs):.3f}",
                  f"{min(at480):.3f}" if at480 else "-", f"{r['eq6_reduction_x']:.1f} ({r['eq6_oracle_reduction_x']:.1f})",
                  str(r["learning"]["reached_at"]),
                  f"{r['instrument_identified']['fn_Hz']:.0f} / {r['instrument_true']['fn_Hz']:.0f}")
    con.print(t)


def _print(res: dict) -> None:
    from rich.table import Table

    from hystbench.reports.console import console

    con = console()
    if res.get("family"):
        _print_family(res["family"])
    if res.get("independent"):
        print_independent(res["independent"], con)
    for rig, r in res["rigs"].items():
        t = Table(title=f"{rig}: accuracy (%) on recordings the fit did not see (fit: {r['fit_recordings']} "
                        f"recordings, {r['fit_seconds']:.1f} s)")
        for col in ("f (Hz)", "A-pp", "range (N)", "Eq. 1", "Eq. 6 (paper)", "ours", "averaged noise (N)"):
            t.add_column(col, justify="right")
        for j in r["judge"]:
            a = j["accuracy_pct"]
            t.add_row(f"{j['frequency_Hz']:g}", f"{j['current_pp_A']:g}", f"{j['force_range_N']:.4g}",
                      f"{a['nonhysteretic']:.3f}", f"{a['paper']:.3f}", f"{a['best']:.3f}",
                      f"{j['averaged_force_noise_N']:.2g}")
        con.print(t)
    t = Table(title="closed loop (learning): max |dF| / noise floor per iteration")
    for col in ("rig", "model", "reference", "start", "ratio per iteration", "reached"):
        t.add_column(col)
    for c in res["closed_loop"]:
        t.add_row(c["rig"], c["model"], c["reference"], c["start"], " ".join(f"{r['ratio']:.1f}" for r in c["iterations"]),
                  str(c["reached_at"]))
    con.print(t)
    t = Table(title="targets")
    for col in ("target", "measured", "pass"):
        t.add_column(col)
    for row in res["targets"]:
        t.add_row(row["target"], row["measured"], "n/a" if row["pass"] is None else "yes" if row["pass"] else "NO")
    con.print(t)
    if "rigs" not in res or not res["rigs"]:
        return


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m benchmarks compensator", description=__doc__.split("\n\n")[0])
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--out", help="folder for the figures (PNG)")
    ap.add_argument("--quick", action="store_true", help="80 and 320 Hz only, fewer closed loops")
    ap.add_argument("--family", action="store_true", help="the foreign benches only")
    ap.add_argument("--independent", action="store_true", help="the independent bench's family only")
    args = ap.parse_args(argv)
    t0 = time.monotonic()
    res = {"rigs": {}, "closed_loop": [], "targets": []}
    if not (args.family or args.independent):
        res = run(quick=args.quick)
    if args.family or not args.independent:
        res["family"] = family(args.quick)
        res["targets"] += family_targets(res["family"])
    if args.independent or not args.family:
        res["independent"] = independent_family()
        res["targets"] += independent_targets(res["independent"])
    res["seconds"] = time.monotonic() - t0
    if args.out:
        res["figures"] = [str(p) for p in figures(res, Path(args.out))]
    for r in res["rigs"].values():
        r.pop("_loops", None)
        r.pop("_iron", None)
    if args.json:
        print(json.dumps(res, indent=2, default=lambda x: x.tolist() if isinstance(x, np.ndarray) else float(x)))
    else:
        _print(res)
        print(f"{res['seconds']:.1f} s" + (f"; figures in {args.out}" if args.out else ""))
    return 0


if __name__ == "__main__":
    sys.exit(main())
