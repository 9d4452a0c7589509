"""``hystbench diagnose``: where a bench day differs from its simulation, what physics was left out,
its parameters, and the held-out proof (issue 13).

    hystbench diagnose SWEEP_DIR [SWEEP_DIR ...] [--baseline EFFECT,...] [--candidates EFFECT,...]
                       [--json] [--report DIR]

Inputs: sweep folders of the recording format (a folder may hold a whole bench day, its rigs told apart
by the sidecars, or one rig's sweep), MCAP logs (read as ``hystbench export`` reads them), or measured
material loss tables (``.csv`` with their sidecar), which take the loss-separation path (a material's
sine table and MagNet triangular/trapezoidal ``_shapes`` table are diagnosed together).  Every input
is read and checked, and ``--report`` is checked, before the diagnosis runs; the report is written
whole or not at all.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any, Callable

from ..errors import ConfigError, RecordingError
from .args import path_arg

__all__ = ["register", "cmd_diagnose", "effect_list", "read_inputs"]


def effect_list(option: str) -> Callable[[str], list[str]]:
    """``EFFECT,EFFECT,...`` of catalogue names (argparse names ``option`` in its error); an empty
    string is an empty list (``--baseline ''``: the analyst's model has none of the effects)."""

    def parse(text: str) -> list[str]:
        from ..config.effects import CATALOGUE

        names = [n.strip() for n in text.split(",") if n.strip()]
        for n in names:
            if n not in CATALOGUE:
                raise argparse.ArgumentTypeError(f"unknown effect {n!r}; known: {', '.join(CATALOGUE)}")
        if len(set(names)) < len(names):
            raise argparse.ArgumentTypeError(f"an effect is named twice in {text!r}")
        return names

    parse.__name__ = option  # argparse's "invalid <name> value" fallback
    return parse


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add ``diagnose`` to the CLI's subparsers."""
    p = subparsers.add_parser("diagnose", help="locate, name, model and prove what the simulation leaves out",
                              description="hystbench diagnose: where a bench day differs from its simulation, what physics "
                                          "was left out, its parameters, and the held-out proof.")
    p.add_argument("inputs", nargs="+", type=path_arg, metavar="SWEEP_DIR",
                   help="sweep folders (one may hold a whole bench day, or one rig each), MCAP logs (.mcap) or "
                        "material loss tables (.csv)")
    p.add_argument("--baseline", type=effect_list("--baseline"), default=None, metavar="EFFECT,...",
                   help="the effects of your model of the bench (default: each rig preset's own)")
    p.add_argument("--candidates", type=effect_list("--candidates"), default=None, metavar="EFFECT,...",
                   help="the effects to try (default: every catalogue effect not in the baseline)")
    p.add_argument("--json", action="store_true", help="print the stable JSON document instead of the table")
    p.add_argument("--report", type=path_arg, default=None, metavar="DIR",
                   help="write a markdown page with its figures into DIR")
    p.add_argument("--overwrite", action="store_true", help="write into an existing, non-empty --report")
    p.set_defaults(func=cmd_diagnose)


def _is_loss_table(path: Path) -> bool:
    return path.is_file() and path.suffix.lower() == ".csv"


def _rig_folders(path: Path) -> list[Path]:
    """The subfolders holding recordings, when ``path`` itself holds none: a bench day written one
    folder per rig; empty otherwise (the folder is then read as a sweep, and refused if empty)."""
    if any(path.glob("*.csv")):
        return []
    return sorted(sub for sub in path.iterdir() if sub.is_dir() and any(sub.glob("*.csv")))


def _refuse_a_folder_of_tables(path: Path) -> None:
    """A folder whose sidecars all say a material table's ``kind`` is no bench day: say so, and how to
    give the tables (its recordings' reader would ask for a ``rig``)."""
    from ..formats.material_data import LAYOUTS

    kinds = []
    for side in sorted(path.glob("*.json"))[:1000]:
        try:
            kinds.append(json.loads(side.read_bytes()[:1 << 20]).get("kind") if side.stat().st_size < 1 << 20 else None)
        except (OSError, ValueError, AttributeError):
            return  # the recordings' reader names what is wrong with it
    if kinds and all(k in (*LAYOUTS, "waveform") for k in kinds):
        raise RecordingError(f"{path}: a folder of material tables ({', '.join(sorted(set(kinds)))}), not a bench "
                             f"day's recordings: give the tables themselves (hystbench diagnose {path}/*.csv)")


def read_inputs(paths: list[Path]) -> list[Any]:
    """The recordings of every sweep folder and MCAP log, in the order given (each folder sorted by
    ``read_sweep``: by rig, then operating point).  A folder may hold a whole bench day, several rigs
    told apart by the sidecars' ``rig``, or one subfolder per rig; a folder or log with fewer than
    two recordings is refused."""
    from ..analysis.log_recordings import read_mcap_segments
    from ..formats.recording import read_sweep

    recs: list[Any] = []
    seen: dict[Path, Path] = {}
    for path in paths:  # a recording given twice would count twice: a false drift on a clean day
        where = path.resolve()
        twice = next((given for p, given in seen.items() if where == p or p in where.parents or where in p.parents), None)
        if twice is not None:
            raise ConfigError(f"{path}: given twice ({'the same as' if where == twice.resolve() else 'overlaps'} "
                              f"{twice}); give each recording once")
        seen[where] = path
        if path.is_dir():
            _refuse_a_folder_of_tables(path)
            rigs = _rig_folders(path)  # a day written one folder per rig (simulate-bench-day)
            part, what = [r for sub in rigs for r in read_sweep(sub)] if rigs else read_sweep(path), "sweep"
        elif path.is_file() and path.suffix.lower() == ".mcap":
            part, what = read_mcap_segments(path), "log"
        elif not path.exists():
            raise RecordingError(f"{path}: no such folder or file")
        else:
            raise RecordingError(f"{path}: not a sweep folder, an MCAP log (.mcap) or a loss table (.csv)")
        if len(part) < 2:  # read_sweep and the log reader refuse an empty one
            r = part[0]
            raise RecordingError(f"{path}: only one recording ({r.rig} at {r.frequency_hz:g} Hz, {r.current_pp_a:g} "
                                 f"A-pp); a diagnosis needs several operating points per {what}")
        recs += part
    _refuse_copies(recs)
    return recs


def _refuse_copies(recs: list[Any]) -> None:
    """A recording copied under another name (into the same folder, or another given) would count
    its evidence twice, as a folder given twice does: refused, naming both."""
    import hashlib

    from ..analysis.method import recording_name

    seen: dict[str, Any] = {}
    for rec in recs:
        h = hashlib.blake2b(digest_size=16)
        for name in sorted(rec.channels):
            h.update(name.encode())
            h.update(rec.channels[name].tobytes())
        first = seen.setdefault(h.hexdigest(), rec)
        if first is not rec:
            raise RecordingError(f"{recording_name(rec)}: the same samples as {recording_name(first)}; a recording "
                                 "counted twice would overstate its evidence (give each recording once)")


def cmd_diagnose(args: argparse.Namespace) -> int:
    """`hystbench diagnose`: read and check everything, then diagnose with a progress bar; print the
    table (or ``--json``), write ``--report``."""
    from contextlib import nullcontext

    from ..formats.outputs import output_folder

    paths = [Path(p) for p in args.inputs]
    if any(_is_waveform_table(p) for p in paths):
        return _waveform_tables(paths, args)
    tables = [p for p in paths if _is_loss_table(p)]
    for p in tables:  # a recording's CSV given by itself: the loss-table reader would ask for its 'material'
        with open(p, "rb") as fh:
            if fh.readline(200).split(b",")[0].strip().lstrip(b"\xef\xbb\xbf") == b"time_s":
                raise ConfigError(f"{p}: a recording (its first column is time_s), not a loss table; give the sweep "
                                  f"folder that holds it ({p.parent}) to diagnose a bench day")
    if tables and len(tables) < len(paths):
        raise ConfigError(f"{tables[0]}: a loss table is diagnosed on its own, not with sweeps or logs; "
                          "give loss tables or recordings, not both")
    if tables and (args.baseline is not None or args.candidates is not None):
        raise ConfigError(f"{'--baseline' if args.baseline is not None else '--candidates'}: a loss table's "
                          "diagnosis has its own term library (classical, excess, generic rate terms); the option is "
                          "for recordings")
    groups = _loss_groups(tables, args) if tables else []
    # --report is checked (exists? writable beside?) before the work, and written only if it all succeeds
    report = (output_folder(args.report, overwrite=args.overwrite, option="--report") if args.report is not None
              else nullcontext())
    with report as stage:  # written whole before anything is printed: a closed stdout loses no report
        if tables:
            results, page = _loss_tables(groups, stage)
        else:
            d = _run(read_inputs(paths), args)
            page = None
            if stage is not None:
                from ..reports.diagnosis import render_report

                page = stage.final(render_report(d, stage.path))
    if tables:
        return _print_loss_tables(results, page, args)
    _print_warnings(d.warnings)
    if args.json:
        print(json.dumps(d.to_json(), indent=2, allow_nan=False))
        return 0
    from ..reports.console import console
    from ..reports.diagnosis import print_summary

    con = console()
    print_summary(d, con)
    if page is not None:
        con.print(f"report: {page}")
    return 0


def _print_warnings(warnings: list[str]) -> None:
    import sys

    for w in warnings:
        print(f"hystbench diagnose: warning: {w}", file=sys.stderr, flush=True)


def _run(recs: list[Any], args: argparse.Namespace) -> Any:
    from ..analysis.diagnosis import diagnose
    from ..reports.console import progress

    with progress() as bar:
        task = bar.add_task(f"diagnosing {len(recs)} recordings", total=None)
        return diagnose(recs, baseline=args.baseline, candidates=args.candidates,
                        progress=lambda msg: bar.update(task, description=msg))


def _loss_groups(tables: list[Path], args: argparse.Namespace) -> list[list[Any]]:
    """Every table read and checked, grouped (a material's sine and shapes tables together), before any
    work."""
    from ..analysis.diagnosis.loss_separation import loss_table_groups

    return loss_table_groups(tables)


def _loss_tables(groups: list[list[Any]], stage: Any) -> tuple[list[dict[str, Any]], Path | None]:
    """Measured loss tables: the loss-separation diagnosis per group of tables (rate-independent
    baseline calibrated at the lowest frequencies, the rest held out; then across the band), and the
    report's page when ``--report`` is staged."""
    from rich.markup import escape

    from ..analysis.diagnosis.loss_separation import diagnose_loss_table
    from ..reports.console import progress

    results = []
    with progress() as bar:  # a large table (250 000 rows) takes minutes
        task = bar.add_task("loss tables", total=len(groups))
        for g in groups:
            bar.update(task, description=f"diagnosing {escape(g[0].path.name)} ({sum(len(t) for t in g)} rows, two splits)")
            results.append(diagnose_loss_table(g))
            bar.advance(task)
    if stage is None:
        return results, None
    from ..reports.diagnosis import render_loss_report

    return results, stage.final(render_loss_report(results, stage.path))


def _print_loss_tables(results: list[dict[str, Any]], page: Path | None, args: argparse.Namespace) -> int:
    """The JSON document, or a row per split of each table and its verdict (after the report is written)."""
    if args.json:
        print(json.dumps(results[0] if len(results) == 1 else results, indent=2, allow_nan=False))
        return 0
    from rich.markup import escape
    from rich.table import Table

    from ..analysis.diagnosis.loss_separation import SPLITS
    from ..reports.console import console

    t = Table(title="loss tables: a rate-independent baseline calibrated on part of the frequencies, the rest held out")
    for col in ("table", "calibrated at (frequencies)", "named", "held-out rms before (log10)", "after", "improvement"):
        t.add_column(col, overflow="fold")
    for r in results:  # the prescribed split, then the other one (a proof across the band)
        names = " + ".join(Path(p).name for p in r.get("paths", [r["path"]]))
        for label, s in ((names, r), ("", r["other_split"])):
            if "refused" in s:  # too few frequencies for this split
                t.add_row(escape(label), SPLITS[s["split"]], "not possible: too few frequencies", "", "", "")
                continue
            imp = s.get("improvement")
            t.add_row(escape(label), SPLITS[s["split"]], escape(", ".join(s["effects"]) or "none"),
                      f"{s['residual_before_log10']:.3f}", f"{s['residual_after_log10']:.3f}",
                      "n/a" if imp is None else f"{imp:.2f}x")
    con = console()
    con.print(t)
    for r in results:
        con.print(f"{escape(' + '.join(Path(p).name for p in r.get('paths', [r['path']])))}: {escape(r['verdict'])}")
    if page is not None:
        con.print(f"report: {page}")
    return 0


def _is_waveform_table(path: Path) -> bool:
    """A ``.csv`` whose sidecar says ``kind: waveform`` (measured B(t)/H(t) rows, not a loss table)."""
    if not _is_loss_table(path):  # a folder (``diagnose .``) has no suffix to replace
        return False
    side = path.with_suffix(".json")
    if not side.is_file():  # not a FIFO's open either: the reader names it
        return False
    try:
        return json.loads(side.read_text(encoding="utf-8")).get("kind") == "waveform"
    except (OSError, ValueError, AttributeError):
        return False  # the loss-table reader names what is wrong with the sidecar


def _waveform_tables(paths: list[Path], args: argparse.Namespace) -> int:
    """Measured B(t)/H(t) rows: the waveform diagnosis (analysis.diagnosis.waveforms), one table at a time."""
    from contextlib import nullcontext

    from ..formats.material_data import read_waveform_table
    from ..formats.outputs import output_folder

    if len(paths) != 1:
        raise ConfigError(f"{paths[0]}: a waveform table is diagnosed on its own; give one table")
    if args.baseline is not None or args.candidates is not None:
        raise ConfigError(f"{'--baseline' if args.baseline is not None else '--candidates'}: a waveform table's "
                          "diagnosis has its own terms; the option is for recordings")
    from ..analysis.diagnosis.waveforms import diagnose_waveforms
    from ..reports.console import console, progress

    table = read_waveform_table(paths[0])  # checked before --report is staged
    report = (output_folder(args.report, overwrite=args.overwrite, option="--report") if args.report is not None
              else nullcontext())
    with report as stage:
        with progress() as bar:
            task = bar.add_task(f"diagnosing {len(table)} waveforms", total=None)
            d = diagnose_waveforms(table, say=lambda msg: bar.update(task, description=msg))
        page = None
        if stage is not None:
            from ..reports.waveform_report import render_waveform_report

            page = stage.final(render_waveform_report(d, stage.path))
    if args.json:
        print(json.dumps(d.to_json(), indent=2, allow_nan=False))
        return 0
    from rich.markup import escape
    from rich.table import Table

    s = d.summary
    rb, ra = s["held_out_rows"]["before"], s["held_out_rows"]["after"]
    t = Table(title="waveforms: H(t) of each row predicted by the model calibrated on the other rows "
                    "(after the warm-up; Paderborn test: relative L2 < 0.15, correlation > 0.95)")
    for col in ("row", "degC", "rel. L2 before", "after", "corr before", "after"):
        t.add_column(col)
    for i in range(s["rows"]):
        t.add_row(str(i), f"{s['temperatures_c'][i]:g}", f"{rb['rel_l2'][i]:.3f}", f"{ra['rel_l2'][i]:.3f}",
                  f"{rb['corr'][i]:.4f}", f"{ra['corr'][i]:.4f}")
    con = console()
    con.print(t)
    for name, p in (s["parameters"]["named"] or s["parameters"]["baseline"]).items():
        con.print(f"  {escape(name)} = {p['value']:.4g} +- {p['std']:.2g} {escape(p['unit'])}")
    for name, p in s.get("interpretation", {}).items():
        con.print(f"  {escape(name)} = {p['value']:.4g} {escape(str(p['unit']))}")
    con.print(escape(s["verdict"]))
    if page is not None:
        con.print(f"report: {page}")
    return 0
