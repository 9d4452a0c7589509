"""Command-line wiring of the measurement method: ``estimate``, ``identify`` and ``paper``.

``register(subparsers)`` adds the three subcommands to the ``hystbench`` parser; the CLI's ``main``
turns a :class:`~hystbench.errors.BenchError` into exit status 2 with the message on stderr.
The work is done in :mod:`.method`, :mod:`.identification`, :mod:`.force_error` and
:mod:`.paper`, imported when a command runs.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

from ..errors import RecordingError
from .args import nonnegative_int

__all__ = ["register", "identify_folder"]


def _console():
    from ..reports.console import console

    return console()


def _fmt(x: float, digits: int = 4) -> str:
    return f"{x:.{digits}g}"


# --- estimate -----------------------------------------------------------------------------------
def cmd_estimate(args) -> int:
    from ..analysis.method import estimate
    from ..formats.recording import read_recording

    if Path(args.path).suffix.lower() == ".mcap":
        from ..formats.mcaplog import read_mcap_recording

        rec = read_mcap_recording(args.path, segment=args.segment)
    else:
        rec = read_recording(args.path)
    result = estimate(rec)
    if result["outliers_excluded"]:
        from ..analysis.method import outlier_summary

        print(f"hystbench estimate: warning: {result['recording']}: left out as outliers (far off the fitted "
              f"waveform): {outlier_summary(result['outliers'])}", file=sys.stderr)
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
def _instrument_report(name, fit, eddy, reference: str, own_is_model: bool) -> dict:
    out = {"kind": "instrument", "sweep": name, **fit.as_dict(),
           "points": int(fit.response.freq_hz.size),
           "frequency_range_Hz": [float(fit.response.freq_hz[0]), float(fit.response.freq_hz[-1])],
           "benchmark": own_is_model, "reference": reference, "eddy": eddy.as_dict(),
           "eddy_lag_flag": eddy.significant}
    if not own_is_model:
        out["note"] = ("the two-filter fit above is this coil's own: it absorbs any eddy lag of its magnet, so "
                       "the instrument model is the reference's")
    return out


def _ecore_report(name, recs) -> dict:
    from ..analysis.method import measure_delays

    points, by_amp = [], {}
    for rec in recs:
        d = measure_delays(rec)
        points.append({"recording": d.recording, **d.as_dict(), "frequency_Hz": rec.frequency_hz,
                       "frequency_true_Hz": d.frequency_hz, "current_pp_A": rec.current_pp_a,
                       "theta_hyst_deg": d.phase_deg("hysteresis"),
                       "theta_hyst_std_deg": d.phase_std_deg("hysteresis")})
        by_amp.setdefault(f"{rec.current_pp_a:g}", {})[f"{rec.frequency_hz:g}"] = d.phase_deg("hysteresis")
    return {"kind": "hysteresis", "sweep": name, "rig": recs[0].rig, "points": points,
            "theta_hyst_deg_by_amplitude": by_amp}


def identify_folder(folder: str | Path, progress=None) -> dict:
    """``hystbench identify`` as data: a sweep, or a folder of sweeps, identified; ``progress`` is
    a rich Progress or None."""
    from ..config import load_rig
    from ..analysis.identification import eddy_lag, fit_instrument, frequency_response, is_benchmark, preset_instrument
    from ..analysis.identification import read_sweeps

    task = None if progress is None else progress.add_task(f"reading {folder}", total=None)

    def say(text: str) -> None:
        if progress is not None:
            progress.update(task, description=text)

    sweeps = read_sweeps(folder)
    kinds = {n: load_rig(recs[0].rig).get("actuator") for n, recs in sweeps.items()}
    dropped = {n: [] for n in sweeps}
    coils, fits = {}, {}
    for n, recs in sweeps.items():
        if kinds[n] == "voicecoil":
            say(f"{n}: frequency response and instrument fit ({len(recs)} recordings)")
            coils[n] = frequency_response(recs, dropped=dropped[n])
            fits[n] = fit_instrument(coils[n])
    bench = next((n for n, r in coils.items() if is_benchmark(r.rig)), None)
    reports = {}
    for n, recs in sweeps.items():
        if kinds[n] == "voicecoil":
            if bench is not None:
                ref_model, ref = fits[bench].model, f"the {bench!r} sweep's fit"
            else:
                ref_model, ref = preset_instrument(coils[n].rig), (f"the {coils[n].rig} preset's instrument model "
                                                                   "(no ferrite sweep to benchmark against)")
            reports[n] = _instrument_report(n, fits[n], eddy_lag(coils[n], ref_model, ref), ref, n == bench)
            reports[n]["dropped_points"] = [{"recording": w, "reason": why} for w, why in dropped[n]]
        elif kinds[n] == "ecore":
            say(f"{n}: the method's delays ({len(recs)} recordings)")
            reports[n] = _ecore_report(n, recs)
        else:
            raise RecordingError(f"{folder}: sweep {n!r} is of a {kinds[n]} ({recs[0].rig}); identify takes "
                                 "voice-coil or E-core sweeps")
    return next(iter(reports.values())) if len(reports) == 1 else {"sweeps": reports}


def _print_identify(rep: dict, con) -> None:
    from rich.table import Table

    if rep["kind"] == "instrument":
        t = Table(title=f"{rep['sweep']}: {rep['rig']}, {rep['points']} points, "
                        f"{rep['frequency_range_Hz'][0]:.4g}-{rep['frequency_range_Hz'][1]:.4g} Hz")
        for col in ("parameter", "fitted", "±", "paper"):
            t.add_column(col, justify="left" if col == "parameter" else "right")
        paper = {"fn_Hz": "4450", "zeta_n": "0.012", "f0_Hz": "31000", "zeta_0": "1", "force_constant_N_per_A": "-"}
        for k, v in rep["parameters"].items():
            t.add_row(k, _fmt(v, 5), _fmt(rep["std"][k], 2), paper.get(k, ""))
        t.add_row("phase at 320 Hz (deg)", f"{rep['phase_at_320Hz_deg']:.3f}",
                  _fmt(rep["phase_at_320Hz_std_deg"], 2), "about -1.28")
        con.print(t)
        con.print(f"fit residuals: {rep['rms_phase_residual_deg']:.2f} deg, {rep['rms_magnitude_residual_pct']:.2f} % "
                  f"rms (reduced chi2 {rep['reduced_chi2']:.3g})")
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


def cmd_identify(args) -> int:
    from ..reports.console import progress

    with progress() as bar:
        rep = identify_folder(args.sweep_dir, progress=bar)
    if args.json:
        print(json.dumps(rep, indent=2))
        return 0
    con = _console()
    for r in (rep["sweeps"].values() if "sweeps" in rep else [rep]):
        _print_identify(r, con)
    return 0


# --- paper --------------------------------------------------------------------------------------
def cmd_paper(args) -> int:
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


def register(subparsers) -> None:
    """Add ``estimate``, ``identify`` and ``paper`` to the ``hystbench`` subcommands."""
    p = subparsers.add_parser("estimate", help="the method's three delays from one recording (paper Sec. III)")
    p.add_argument("path", help="recording: STEM, STEM.csv or STEM.json, or an MCAP log (LOG.mcap)")
    p.add_argument("--segment", type=nonnegative_int,
                   help="which operating point of an MCAP log (default: its only one)")
    p.add_argument("--json", action="store_true", help="print JSON instead of a table")
    p.set_defaults(func=cmd_estimate)

    p = subparsers.add_parser("identify", help="instrument model from voice-coil sweeps, theta_hyst from E-core "
                                               "sweeps (a sweep folder or a folder of sweeps)")
    p.add_argument("sweep_dir", help="sweep folder (one recording per frequency), or a folder of them")
    p.add_argument("--json", action="store_true", help="print JSON instead of tables")
    p.set_defaults(func=cmd_identify)

    p = subparsers.add_parser("paper", help="the whole method on the simulated rig, beside the paper's numbers")
    p.add_argument("--out", default="paper-output", help="folder for figures and paper.json (default paper-output)")
    p.add_argument("--quick", action="store_true", help="a reduced grid (a few seconds; for a first look and tests)")
    p.add_argument("--save-recordings", action="store_true",
                   help="also write every simulated sweep under OUT/sweeps/ (about 200 MB)")
    p.add_argument("--overwrite", action="store_true", help="write into an existing, non-empty --out")
    p.set_defaults(func=cmd_paper)

