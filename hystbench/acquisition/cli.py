"""The ``hystbench`` command line.  Nothing imports this module; it imports what each command needs
when that command runs, so ``hystbench --help`` stays instant."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from .. import __version__
from ..errors import BenchError

__all__ = ["main"]


def _floats(text: str) -> list[float]:
    try:
        return [float(x) for x in text.split(",") if x.strip()]
    except ValueError as err:
        raise argparse.ArgumentTypeError(f"expected comma-separated numbers, got {text!r}") from err


def _add_rig_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--rig", default="ecore_pm", help="rig preset name or TOML path (default: ecore_pm)")
    p.add_argument("--fs", type=float, default=100_000.0, help="sample rate, Hz (default 100000)")
    p.add_argument("--duration", type=float, default=1.0, help="seconds per recording (default 1)")
    p.add_argument("--effect", action="append", default=[], metavar="NAME=VALUE",
                   help="switch an effect: NAME=on|off, NAME=<number> or NAME.param=<number> (repeatable)")
    p.add_argument("--seed", type=int, default=0, help="noise seed (default 0)")
    p.add_argument("--overwrite", action="store_true", help="replace existing recordings of the same name")


def _simulate_one(args, freq_hz: float, ipp_a: float, seed: int):
    from ..sim_backend.effects import parse_effect_args
    from ..sim_backend.rig import SimulatedRig
    from .recording import Recording

    rig = SimulatedRig(args.rig, fs_hz=args.fs, seed=seed, effects=parse_effect_args(args.effect),
                       frequency_hz=freq_hz, current_pp_a=ipp_a)
    block = rig.record(args.duration)
    return Recording(path=None, fs_hz=rig.fs_hz, channels=dict(block.channels), metadata=rig.metadata())


def cmd_simulate(args) -> int:
    from .recording import write_recording

    rec = _simulate_one(args, args.freq, args.ipp, args.seed)
    csv_path, json_path = write_recording(rec, args.out, overwrite=args.overwrite)
    print(f"wrote {csv_path} and {json_path} ({rec.n} samples at {rec.fs_hz:g} Hz)")
    return 0


def _sweep(args, out: Path) -> list:
    from rich.progress import Progress

    from .recording import write_sweep

    points = [(f, i) for i in args.ipp for f in args.freqs]
    recs = []
    with Progress(transient=True) as progress:
        task = progress.add_task(f"simulating {args.rig}", total=len(points))
        for n, (f, i) in enumerate(points):
            recs.append(_simulate_one(args, f, i, args.seed + n))
            progress.advance(task)
    write_sweep(recs, out, overwrite=args.overwrite)
    return recs


def cmd_simulate_sweep(args) -> int:
    recs = _sweep(args, Path(args.out))
    print(f"wrote {len(recs)} recordings to {args.out}")
    return 0


def cmd_effects(args) -> int:
    from rich.table import Table

    from .console import console

    from ..sim_backend.effects import CATALOGUE

    table = Table(title="physical effects of the simulated rig (off unless a preset or --effect turns them on)")
    for col in ("name", "what it is", "parameters (defaults)"):
        table.add_column(col)
    for e in CATALOGUE.values():
        params = ", ".join(f"{k}={v}" + (" *" if k == e.primary else "") for k, v in e.defaults.items())
        table.add_row(e.name, e.description, params)
    console().print(table)
    print("* the parameter that NAME=<number> sets")
    return 0


def cmd_rigs(args) -> int:
    from .operating_points import operating_points

    rows = operating_points()
    if args.json:
        print(json.dumps(rows, indent=2))
        return 0
    from rich.table import Table

    from .console import console

    table = Table(title="rig presets at their operating points (static MEC, Eq. 1)")
    for col in ("rig", "actuator", "f (Hz)", "I (A-pp)", "force min (N)", "force max (N)", "paper"):
        table.add_column(col, no_wrap=col != "paper")
    for r in rows:
        table.add_row(r["rig"], r["actuator"], f"{r['frequency_Hz']:g}", f"{r['current_pp_A']:g}",
                      _fmt(r.get("force_min_N")), _fmt(r.get("force_max_N")), r.get("paper", ""))
    console().print(table)
    return 0


def _fmt(x) -> str:
    return "-" if x is None else f"{x:.2f}"


def cmd_force_map(args) -> int:
    from .figures import force_map_figure

    path = force_map_figure(args.rig, Path(args.out))
    print(f"wrote {path}")
    return 0


def cmd_fit_material(args) -> int:
    from .material_report import run_material_fit

    result = run_material_fit(Path(args.out), refit=args.refit)
    if args.json:
        print(json.dumps(result, indent=2, default=str))
    else:
        for key, value in result.items():
            print(f"{key}: {value}")
    return 0


def cmd_bench(args) -> int:
    import importlib.util

    root = Path(__file__).resolve().parents[2] / "benchmarks"
    path = root / f"bench_{args.name}.py"
    if not path.exists():
        known = sorted(p.stem.removeprefix("bench_") for p in root.glob("bench_*.py"))
        raise BenchError(f"no benchmark {args.name!r} in {root}; known: {', '.join(known) or 'none'}"
                         " (benchmarks live in the source checkout)")
    spec = importlib.util.spec_from_file_location(f"hystbench_bench_{args.name}", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return int(module.main(args.rest) or 0)


def cmd_demo(args) -> int:
    """The main job: the bench service live (a sweep through the emulated instruments, estimates
    over zenoh, an MCAP log), the paper's sweeps as recordings with their delays, the whole method."""
    from .commands_method import cmd_paper
    from rich.markup import escape

    from .commands_pipeline import demo_live, demo_sweeps
    from .console import console

    out = Path(args.out)
    console().rule("live: the daemon's pipeline, a sweep through the emulated instruments, estimates over zenoh")
    live = demo_live(out / "live", seconds=6.0)
    console().print(live["summary"])
    status, failed = demo_sweeps(out)
    if failed:
        console().print(f"[bold red]the sweeps through the drivers failed[/]: {escape(failed)}\n"
                        "(their files removed; the offline part follows)")
    return status or cmd_paper(argparse.Namespace(out=str(out / "paper"), quick=False, save_recordings=False))


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="hystbench", description=__doc__.split(".")[0])
    parser.add_argument("--version", action="version", version=f"hystbench {__version__}")
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("simulate", help="write one recording from the simulated rig")
    _add_rig_args(p)
    p.add_argument("--freq", type=float, required=True, help="excitation frequency, Hz")
    p.add_argument("--ipp", type=float, required=True, help="peak-to-peak current, A")
    p.add_argument("--out", required=True, help="output stem (writes STEM.csv and STEM.json)")
    p.set_defaults(func=cmd_simulate)

    p = sub.add_parser("simulate-sweep", help="write a sweep folder from the simulated rig")
    _add_rig_args(p)
    p.add_argument("--freqs", type=_floats, default=[40, 80, 160, 320, 480], help="Hz, comma-separated")
    p.add_argument("--ipp", type=_floats, default=[1.4], help="A-pp, comma-separated")
    p.add_argument("--out", required=True, help="output folder")
    p.set_defaults(func=cmd_simulate_sweep)

    p = sub.add_parser("effects", help="list the simulated rig's physical effects")
    p.set_defaults(func=cmd_effects)

    p = sub.add_parser("rigs", help="list rig presets with their force range at the operating point")
    p.add_argument("--json", action="store_true")
    p.set_defaults(func=cmd_rigs)

    p = sub.add_parser("force-map", help="static force map F(i, z) of an E-core (paper Fig. 3) as PNG")
    p.add_argument("--rig", default="ecore_pm")
    p.add_argument("--out", default="force_map.png")
    p.set_defaults(func=cmd_force_map)

    p = sub.add_parser("fit-material", help="hysteresis model vs the real measured B-H loops (PNG + table)")
    p.add_argument("--out", default="material-fit", help="output folder")
    p.add_argument("--refit", action="store_true", help="fit again instead of using the shipped parameters")
    p.add_argument("--json", action="store_true")
    p.set_defaults(func=cmd_fit_material)

    p = sub.add_parser("bench", help="run a benchmark from benchmarks/ (sim, estimator, ...)")
    p.add_argument("name")
    p.add_argument("rest", nargs=argparse.REMAINDER, help="arguments for the benchmark (e.g. --json)")
    p.set_defaults(func=cmd_bench)

    from . import commands_bench, commands_compensator, commands_method, commands_pipeline

    commands_method.register(sub)  # estimate, identify, paper
    commands_bench.register(sub)  # emulate
    commands_pipeline.register(sub)  # watch, record, replay, export, recover, daemon
    commands_compensator.register(sub)  # model fit|predict, compensate

    p = sub.add_parser("demo", help="the main job on the embedded simulated rig")
    p.add_argument("--out", default="demo-output")
    p.set_defaults(func=cmd_demo)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return args.func(args)
    except BenchError as err:
        print(f"hystbench {args.command}: error: {err}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130
