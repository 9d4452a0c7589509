"""Command-line wiring of the measurement method: ``estimate``, ``identify`` and ``paper``.

``register(subparsers)`` adds the three subcommands to the ``hystbench`` parser; the CLI's ``main``
turns a :class:`~hystbench.errors.BenchError` into exit status 2 with the message on stderr.
The work is done in ``analysis.method``, ``reports.identify`` and ``reports.paper``, imported
when a command runs.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from ..errors import ConfigError
from .args import nonnegative_int, path_arg

__all__ = ["register"]


def _console():
    from ..reports.console import console

    return console()


def _fmt(x: float, digits: int = 4) -> str:
    return f"{x:.{digits}g}"


# --- estimate -----------------------------------------------------------------------------------
def cmd_estimate(args: argparse.Namespace) -> int:
    """`hystbench estimate`: the method's three delays (paper Sec. III) from one recording or one
    segment of an MCAP log."""
    from ..analysis.method import estimate
    from ..formats.recording import read_recording

    if Path(args.path).suffix.lower() == ".mcap":
        from ..analysis.log_recordings import read_mcap_recording

        rec = read_mcap_recording(args.path, segment=args.segment)
    else:
        if args.segment is not None:  # it was ignored: the estimate was of the whole recording
            raise ConfigError(f"--segment {args.segment}: {args.path} is a recording (one operating point); "
                              "--segment picks one of an MCAP log's")
        rec = read_recording(args.path)
    result = estimate(rec)
    if result["outliers_excluded"]:
        from ..analysis.method import outlier_summary

        left = {c: v for c, v in result["outliers"].items() if c != "sense_V"}
        bridged = {c: v for c, v in result["outliers"].items() if c == "sense_V"}
        if any(left.values()):
            print(f"hystbench estimate: warning: {result['recording']}: left out as outliers (far off the fitted "
                  f"waveform): {outlier_summary(left)}", file=sys.stderr)
        if any(bridged.values()):  # the voltage is integrated, so a glitch is bridged, not dropped
            print(f"hystbench estimate: warning: {result['recording']}: bridged by straight lines before the "
                  f"sense voltage was integrated (far off its fitted waveform): {outlier_summary(bridged)}",
                  file=sys.stderr)
    if args.json:
        print(json.dumps(result, indent=2))
        return 0
    from rich.table import Table

    f = result["frequency_Hz"]
    table = Table(title=f"{result['recording']}: {result['rig']}, {result['nominal_frequency_Hz']:g} Hz nominal, "
                        f"{f:.6f} Hz estimated (± {result['frequency_std_Hz']:.2g})")
    for col in ("delay", "µs", "± µs", "deg at f", "Eq. 3 µs", "Eq. 3 deg"):
        table.add_column(col, justify="left" if col == "delay" else "right", no_wrap=True)
    cov = result["covariance_method"]
    for k in ("hysteresis", "instrument", "total"):
        table.add_row(k, f"{1e6 * result['delays_s'][k]:.3f}", f"{1e6 * result['delays_std_s'][k]:.2g}",
                      f"{result['phases_deg'][k]:.4f}", f"{1e6 * cov['delays_s'][k]:.1f}",
                      f"{cov['phases_deg'][k]:.3f}")
    m = result["instrument_model"]
    table.add_row("model", f"{1e6 * m['delay_s']:.3f}", "", f"{m['phase_deg']:.4f}", "", "")
    sq = "" if result["harmonic"] == 1 else "²"
    table.caption = (f"hysteresis = flux behind current, instrument = force behind flux{sq}, total = force behind "
                     f"current{sq}; model = the rig preset's instrument model; Eq. 3 = the paper's covariance "
                     "method")
    con = _console()
    con.print(table)
    con.print(f"theta_hyst = {result['theta_hyst_deg']:.4f} deg; the covariance method resolves one sample "
              f"({1e6 * cov['resolution_s']:.1f} µs); delays at the force's {result['harmonic']} x f component")
    return 0


# --- identify -----------------------------------------------------------------------------------
def _print_identify(rep: dict, con) -> None:
    from rich.table import Table

    if rep["kind"] == "instrument":
        t = Table(title=f"{rep['sweep']}: {rep['rig']}, {rep['points']} points, "
                        f"{rep['frequency_range_Hz'][0]:.4g}-{rep['frequency_range_Hz'][1]:.4g} Hz")
        for col in ("parameter", "fitted", "±", "paper"):
            t.add_column(col, justify="left" if col == "parameter" else "right")
        paper = {"fn_Hz": "4450", "zeta_n": "0.012", "f0_Hz": "31000", "zeta_0": "1", "force_constant_N_per_A": "-"}
        poor = rep.get("poorly_constrained", {})
        for k, v in rep["parameters"].items():
            t.add_row(k, _fmt(v, 5) + (" *" if k in poor else ""), _fmt(rep["std"][k], 2), paper.get(k, ""))
        t.add_row("phase at 320 Hz (deg)", f"{rep['phase_at_320Hz_deg']:.3f}",
                  _fmt(rep["phase_at_320Hz_std_deg"], 2), "about -1.28")
        con.print(t)
        con.print(f"fit residuals: {rep['rms_phase_residual_deg']:.2f} deg, {rep['rms_magnitude_residual_pct']:.2f} % "
                  f"rms (reduced chi2 {rep['reduced_chi2']:.3g})")
        for k, why in poor.items():
            con.print(f"* {k} = {_fmt(rep['parameters'][k], 4)} ± {_fmt(rep['std'][k], 2)}: {why}")
        con.print(f"against {rep['reference']}: {rep['eddy']['verdict']}")
        if "note" in rep:
            con.print(f"note: {rep['note']}")
        for d in rep["dropped_points"]:
            con.print(f"[yellow]left out:[/] {d['reason']}")
        return
    t = Table(title=f"{rep['sweep']}: {rep['rig']}, the method per recording")
    for col in ("f (Hz)", "A-pp", "theta_hyst (deg)", "±", "hysteresis (µs)", "instrument (µs)", "total (µs)"):
        t.add_column(col, justify="right")
    for p in rep["points"]:
        t.add_row(f"{p['frequency_Hz']:g}", f"{p['current_pp_A']:g}", f"{p['theta_hyst_deg']:.4f}",
                  _fmt(p["theta_hyst_std_deg"], 2),
                  *(f"{1e6 * p['delays_s'][k]:.3f}" for k in ("hysteresis", "instrument", "total")))
    con.print(t)


def cmd_identify(args: argparse.Namespace) -> int:
    """`hystbench identify`: the instrument model from voice-coil sweeps and theta_hyst from E-core
    sweeps, for one sweep folder or a folder of them."""
    from ..reports.console import progress
    from ..reports.identify import identify_folder

    with progress() as bar:
        task = bar.add_task(f"reading {args.sweep_dir}", total=None)
        rep = identify_folder(args.sweep_dir, say=lambda text: bar.update(task, description=text))
    if args.json:
        print(json.dumps(rep, indent=2))
        return 0
    con = _console()
    for r in (rep["sweeps"].values() if "sweeps" in rep else [rep]):
        _print_identify(r, con)
    return 0


# --- paper --------------------------------------------------------------------------------------
def cmd_paper(args: argparse.Namespace) -> int:
    """`hystbench paper`: the whole method on the simulated rig, figures and paper.json, beside the
    paper's numbers."""
    import time

    from rich.table import Table

    from ..reports.console import progress as make_progress
    from ..formats.outputs import output_folder
    from ..reports.paper import DEFAULT_GRID, QUICK_GRID, comparison, explanations, run_paper, summary, write_recordings
    from ..reports.paper_figures import paper_figures

    out = Path(args.out)
    grid = QUICK_GRID if args.quick else DEFAULT_GRID
    con = _console()
    start = time.monotonic()
    # everything is written into a staging folder and moves into --out only when all of it is there
    with output_folder(out, overwrite=args.overwrite) as stage, make_progress() as progress:
        res = run_paper(grid, progress=progress)
        task = progress.add_task("drawing figures", total=None)
        res.figures = paper_figures(res, stage.path)
        if args.save_recordings:
            progress.update(task, description="writing the recordings")
            write_recordings(res, stage.path / "sweeps")
        res.figures = [stage.final(p) for p in res.figures]
        rows = comparison(res)
        (stage.path / "paper.json").write_text(json.dumps(summary(res, rows), indent=2))
    table = Table(title="Vrijsen et al. 2013 against the simulated rig", show_lines=True)
    for col in ("quantity", "paper", "hystbench", "note"):
        table.add_column(col, overflow="fold")
    for r in rows:
        table.add_row(r["quantity"], r["paper"], r["hystbench"], r["note"])
    con.print(table)
    con.print("[bold]Why the numbers differ[/]")
    for line in explanations(res):
        con.print(f"- {line}")
    con.print(f"{len(res.figures)} figures and paper.json in {out} ({time.monotonic() - start:.0f} s)")
    return 0


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add ``estimate``, ``identify`` and ``paper`` to the ``hystbench`` subcommands."""
    p = subparsers.add_parser("estimate", help="the method's three delays from one recording (paper Sec. III)")
    p.add_argument("path", type=path_arg, help="recording: STEM, STEM.csv or STEM.json, or an MCAP log (LOG.mcap)")
    p.add_argument("--segment", type=nonnegative_int,
                   help="which operating point of an MCAP log (default: its only one)")
    p.add_argument("--json", action="store_true", help="print JSON instead of a table")
    p.set_defaults(func=cmd_estimate)

    p = subparsers.add_parser("identify", help="instrument model from voice-coil sweeps, theta_hyst from E-core "
                                               "sweeps (a sweep folder or a folder of sweeps)")
    p.add_argument("sweep_dir", type=path_arg, help="sweep folder (one recording per frequency), or a folder of them")
    p.add_argument("--json", action="store_true", help="print JSON instead of tables")
    p.set_defaults(func=cmd_identify)

    p = subparsers.add_parser("paper", help="the whole method on the simulated rig, beside the paper's numbers")
    p.add_argument("--out", type=path_arg, default="paper-output",
                   help="folder for figures and paper.json (default paper-output)")
    p.add_argument("--quick", action="store_true", help="a reduced grid (a few seconds; for a first look and tests)")
    p.add_argument("--save-recordings", action="store_true",
                   help="also write every simulated sweep under OUT/sweeps/ (about 200 MB)")
    p.add_argument("--overwrite", action="store_true", help="write into an existing, non-empty --out")
    p.set_defaults(func=cmd_paper)

