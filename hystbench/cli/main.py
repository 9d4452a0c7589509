"""The ``hystbench`` command line.  Nothing imports this module; it imports what each command needs
when that command runs, so ``hystbench --help`` stays instant."""

from __future__ import annotations

import argparse
import json
import logging
import os
import signal
import sys
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator, NoReturn, Sequence

from .. import __version__
from ..errors import BenchError, ConfigError
from .args import SIM_MAX_IPP_A, float_in, float_list_in, nonnegative_int, path_arg, positive_float, positive_floats
from .signals import noting

__all__ = ["main"]


def _add_rig_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--rig", default="ecore_pm", help="rig preset name or TOML path (default: ecore_pm)")
    p.add_argument("--fs", type=positive_float, default=100_000.0, help="sample rate, Hz (default 100000)")
    p.add_argument("--duration", type=positive_float, default=1.0, help="seconds per recording (default 1)")
    p.add_argument("--effect", action="append", default=[], metavar="NAME=VALUE",
                   help="switch an effect: NAME=on|off, NAME=<number> or NAME.param=<number> (repeatable; "
                        "`hystbench effects` lists each parameter's range)")
    p.add_argument("--seed", type=nonnegative_int, default=0, help="noise seed (default 0)")
    p.add_argument("--overwrite", action="store_true", help="replace existing recordings of the same name")


#: What ``simulate`` and ``simulate-sweep`` hold in memory at once (5 channels of float64: 400 MB);
#: longer runs stream through ``hystbench record``.
MAX_SAMPLES = 10_000_000


def _check_size(args, recordings: int = 1) -> None:
    """Before simulating: the samples fit in memory, and the rig is one a recording can name."""
    from ..config import load_rig, rig_names

    name = load_rig(args.rig)["name"]
    if name not in rig_names():  # the recording format names a rig by its preset (it refused it after the work)
        raise ConfigError(f"--rig {args.rig}: its recordings would name the rig {name!r}, and a recording's rig is a "
                          f"preset's name ({', '.join(rig_names())}); name a variant after the preset it varies")
    n = args.duration * args.fs * recordings
    if args.duration * args.fs < 1:
        raise ConfigError(f"--duration {args.duration:g} s is less than one sample at --fs {args.fs:g} Hz")
    if n > MAX_SAMPLES:
        raise ConfigError(f"--duration {args.duration:g} s at --fs {args.fs:g} Hz x {recordings} recording(s) is "
                          f"{n:.3g} samples; this command holds them in memory, at most {MAX_SAMPLES:.0e} "
                          "(`hystbench record` streams long runs to a log)")


def _simulate_one(args, frequency_hz: float, ipp_a: float, seed: int):
    """One recording of the simulated rig; a clipped one is refused before anything is written (a
    channel beyond its ADC full scale is not a measurement), naming the option to change."""
    from ..config.effects import parse_effect_args
    from ..sim_backend.bench_day import refuse_effects_not_acting
    from ..sim_backend.recordings import simulate_recording
    from .bench_day import refuse_clipped

    effects = parse_effect_args(args.effect)
    refuse_effects_not_acting(args.rig, effects)
    rec = simulate_recording(args.rig, frequency_hz, ipp_a, args.duration, fs_hz=args.fs, seed=seed,
                             effects=effects)
    refuse_clipped(rec)
    return rec


def cmd_simulate(args: argparse.Namespace) -> int:
    """`hystbench simulate`: one recording (STEM.csv + STEM.json) of a simulated rig, to try the
    method with no hardware; an existing output is refused before the simulation runs."""
    from ..formats.outputs import parent_folders
    from ..formats.recording import write_recording

    _check_size(args)
    stem = Path(args.out)
    if str(args.out).endswith(("/", os.sep)) or os.path.isdir(stem) or stem.name in ("", ".", ".."):
        raise ConfigError(f"--out {args.out}: a folder; give the recording's file stem (e.g. {stem / 'run'})")
    stem = stem.with_suffix("") if stem.suffix in (".csv", ".json") else stem
    taken = [p for p in (stem.with_name(stem.name + ".csv"), stem.with_name(stem.name + ".json")) if p.exists()]
    if taken and not args.overwrite:  # before the simulation, not after it
        raise ConfigError(f"--out {args.out}: {taken[0]} exists; give --overwrite to replace it")
    rec = _simulate_one(args, args.freq, args.ipp, args.seed)
    with parent_folders(stem):  # --out new/run: the folder as simulate-sweep makes its own, gone if it fails
        csv_path, json_path = write_recording(rec, args.out, overwrite=args.overwrite)
    print(f"wrote {csv_path} and {json_path} ({rec.n} samples at {rec.fs_hz:g} Hz)")
    return 0


def _sweep(args, out: Path) -> list:
    """One rig running on through the points (as on a bench: slow effects accumulate), each recording
    with its ``start_time_s``; a clipped one is refused before anything is written."""
    from ..config.effects import parse_effect_args
    from ..reports.console import progress as make_progress
    from ..formats.recording import write_sweep
    from ..sim_backend.bench_day import RigBlock, refuse_effects_not_acting, run_rig_block
    from .bench_day import refuse_clipped

    effects = parse_effect_args(args.effect)
    refuse_effects_not_acting(args.rig, effects)
    block = RigBlock.grid(args.rig, args.freqs, args.ipp, periods=0.0, min_duration_s=args.duration, fs_hz=args.fs)
    _check_size(args, len(block.points))
    with make_progress() as progress:
        task = progress.add_task(f"simulating {args.rig}", total=len(block.points))
        recs, _ = run_rig_block(args.rig, block, seed=args.seed, effects=effects,
                                tick=lambda: progress.advance(task))
    for rec in recs:
        refuse_clipped(rec)
    write_sweep(recs, out, overwrite=args.overwrite)
    return recs


def cmd_simulate_sweep(args: argparse.Namespace) -> int:
    """`hystbench simulate-sweep`: a sweep folder (one recording per frequency and current), as
    ``identify`` and ``model fit`` read it."""
    recs = _sweep(args, Path(args.out))
    print(f"wrote {len(recs)} recordings to {args.out}")
    return 0


def cmd_effects(args: argparse.Namespace) -> int:
    """`hystbench effects`: the catalogue of physical effects with each parameter's default and
    range, so ``--effect`` values can be chosen without reading the source."""
    from rich.table import Table

    from ..reports.console import console

    from ..config.effects import CATALOGUE

    table = Table(title="physical effects of the simulated rig (off unless a preset or --effect turns them on)")
    for col in ("name", "what it is", "parameters: default, range"):
        table.add_column(col, no_wrap=col != "what it is")
    for e in CATALOGUE.values():
        params = "\n".join(f"{k} = {v} in {e.ranges[k]}" + (" *" if k == e.primary else "")
                           for k, v in e.defaults.items())
        table.add_row(e.name, e.description, params)
    con = console()
    con.print(table)
    con.print("* the parameter that NAME=<number> sets; a value outside its range is refused. fs/2: half the "
              "sample rate; a list parameter: each element.")
    return 0


def cmd_rigs(args: argparse.Namespace) -> int:
    """`hystbench rigs`: each preset's force range at its operating point (static MEC, Eq. 1) beside
    the paper's, to choose a rig and a current."""
    from ..analysis.operating_points import operating_points
    from ..formats.recording import sidecar_point

    rows = operating_points()
    if args.json:
        print(json.dumps(rows, indent=2))
        return 0
    from rich.table import Table

    from ..reports.console import console

    table = Table(title="rig presets at their operating points (static MEC, Eq. 1)")
    for col in ("rig", "actuator", "f (Hz)", "I (A-pp)", "force min (N)", "force max (N)", "paper"):
        table.add_column(col, no_wrap=col != "paper")
    for r in rows:
        p = sidecar_point(r)
        table.add_row(r["rig"], r["actuator"], f"{p.frequency_hz:g}", f"{p.current_pp_a:g}",
                      _fmt(r.get("force_min_N")), _fmt(r.get("force_max_N")), r.get("paper", ""))
    console().print(table)
    return 0


def _fmt(x) -> str:
    return "-" if x is None else f"{x:.2f}"


def cmd_force_map(args: argparse.Namespace) -> int:
    """`hystbench force-map`: the E-core's static force map F(i, z) (paper Fig. 3) as an image in
    the format of ``--out``'s suffix."""
    from ..reports.figures import check_ecore, force_map_figure
    from ..formats.outputs import output_file

    from matplotlib.backend_bases import FigureCanvasBase

    out = Path(args.out)
    formats = FigureCanvasBase.get_supported_filetypes()  # what savefig writes, by suffix
    if out.suffix[1:].lower() not in formats:
        raise ConfigError(f"--out {out}: give a file name with its format ({', '.join(sorted(formats))}), "
                          f"e.g. {out.stem if out.suffix else out.name}.png")
    check_ecore(args.rig)  # before a file is touched
    try:
        with output_file(out, overwrite=args.overwrite) as tmp:
            force_map_figure(args.rig, tmp)
    except RuntimeError as err:  # a format whose tool is missing (.pgf needs xelatex): nothing written
        raise ConfigError(f"--out {out}: cannot write {out.suffix}: {' '.join(str(err).split())}; "
                          "choose another format, e.g. .png or .pdf") from None
    print(f"wrote {out}")
    return 0


def cmd_fit_material(args: argparse.Namespace) -> int:
    """`hystbench fit-material`: the hysteresis model against the real measured B-H loops (figures
    and a table; ``--refit`` writes fitted TOML files), to show how close the simulated iron is."""
    from ..reports.material_report import run_material_fit
    from ..formats.outputs import output_folder

    from ..config import CONFIG_DIR

    # the shipped material files are what it reads: never its output, even with --overwrite
    with output_folder(args.out, overwrite=args.overwrite, inputs=[CONFIG_DIR / "materials"]) as stage:
        result = run_material_fit(stage.path, refit=args.refit)
        result = _moved(result, stage)
    if args.json:
        print(json.dumps(result, indent=2, default=str))
    else:
        _print_material_fit(result)
    return 0


def _print_material_fit(result: dict) -> None:
    """The fit against the measured loops as a table a person reads (it was printed as dict reprs):
    each loop's error beside the best single-valued curve's (no loop: what hysteresis adds), and where the
    figures went."""
    from rich.table import Table

    from ..reports.console import console

    table = Table(title="the hysteresis model against the measured B-H loops (rms and max error, % of B max)")
    for col in ("loop", "B max (T)", "rms %", "max %", "area ratio", "no loop: rms %", "no loop: max %"):
        table.add_column(col, justify="left" if col == "loop" else "right")
    before = result.get("baseline_errors", {})
    for loop, e in result.get("errors", {}).items():
        b = before.get(loop, {})
        table.add_row(loop, f"{e['b_max_t']:.3g}", f"{e['rms_pct']:.2f}", f"{e['max_pct']:.2f}",
                      f"{e['area_ratio']:.3f}" if "area_ratio" in e else "-",
                      f"{b['rms_pct']:.1f}" if b else "-", f"{b['max_pct']:.1f}" if b else "-")
    con = console()
    con.print(table)
    for label, lag in result.get("phase_lag_deg", {}).items():
        con.print(f"phase lag of B behind H at {label}: {lag:.1f} deg")
    for key in ("material_files", "figures"):  # paths whole, one a line (not wrapped to the terminal)
        for name, path in result.get(key, {}).items():
            print(f"{'material file' if key == 'material_files' else 'figure'} {name}: {path}")
    rest = {k: v for k, v in result.items()
            if k not in ("errors", "baseline_errors", "phase_lag_deg", "material_files", "figures")}
    for key, value in rest.items():  # anything else the fit reports (--json has it whole)
        print(f"{key}: {value}")


def _moved(obj, stage):
    """``obj`` with every path string under the staging folder replaced by its final path."""
    if isinstance(obj, dict):
        return {k: _moved(v, stage) for k, v in obj.items()}
    if isinstance(obj, str) and obj.startswith(str(stage.path)):
        return str(stage.final(obj))
    return obj


#: what ``hystbench demo`` writes under its --out (anything else there, such as make demo's day, is left alone)
DEMO_OUTPUTS = ("live", "sweeps", "paper", "diagnosis", "summary.json", "force_map.png")


def cmd_demo(args: argparse.Namespace) -> int:
    """The main job: the bench service live (a sweep through the emulated instruments, estimates
    over zenoh, an MCAP log), the paper's sweeps as recordings with their delays, the whole method."""
    from rich.markup import escape

    from ..reports.console import console
    from ..reports.demo import demo_sweeps
    from ..reports.demo_live import demo_live
    from .method import cmd_paper
    from .pipeline import format_message

    from ..config import CONFIG_DIR

    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise ConfigError(f"--out {out}: is a file, not a folder")
    earlier = [name for name in DEMO_OUTPUTS if (out / name).exists()]
    if earlier and not args.overwrite:
        raise ConfigError(f"--out {out}: holds an earlier demo's {earlier[0]}; give --overwrite to replace it, "
                          "or another --out")
    if args.day is None and (args.baseline is not None or args.truth is not None):
        raise ConfigError(f"{'--baseline' if args.baseline is not None else '--truth'}: only with --day")
    if args.day is not None:  # read and checked now, not after a minute of the live part
        from ..formats.recording import read_sweep
        from ..reports.demo_diagnosis import truth_line

        read_sweep(args.day)
        if args.truth is not None:
            truth_line(args.truth)
    # --source digitiser: the samples come from the emulated SCPI digitiser through pyvisa-py (issue 15)
    bench_file = CONFIG_DIR / "bench_digitiser.toml" if args.source == "digitiser" else None
    from ..reports.demo import sample_source

    console().rule(f"live: the daemon's pipeline, a sweep, samples from {sample_source(bench_file)}, "
                   "estimates over zenoh")
    live = demo_live(out / "live", seconds=6.0, show=lambda k, msg: print(format_message(k, msg), flush=True),
                     bench_file=bench_file)
    console().print(live["summary"])
    status, failed = demo_sweeps(out, bench_file)
    if failed:
        console().print(f"[bold red]the sweeps through the drivers failed[/]: {escape(failed)}\n"
                        "(their files removed; the offline part follows)")
    status = status or cmd_paper(argparse.Namespace(out=str(out / "paper"), quick=False, save_recordings=False,
                                                    overwrite=True))
    if status == 0:  # last: a diagnosis of a bench day with a concealed effect (issue 13)
        from ..reports.demo_diagnosis import demo_diagnosis

        demo_diagnosis(out / "diagnosis", console(), day=args.day, baseline=args.baseline, truth=args.truth)
    return status


class OneLineParser(argparse.ArgumentParser):
    """An argument parser whose usage error is one line on stderr, ``PROG: error: WHAT (see PROG
    --help)``, and exit status 2: the usage block argparse prints above it buried the line that
    says what is wrong.  Every subparser is of this class (``add_subparsers`` takes the parent's)."""

    def parse_known_args(self, args: Sequence[str] | None = None,  # type: ignore[override]
                         namespace: argparse.Namespace | None = None) -> tuple[argparse.Namespace, list[str]]:
        # an argument nobody takes is the command's error, named with its own --help: argparse
        # hands a subcommand's leftovers up to ``hystbench``, whose message named the wrong command
        namespace, extras = super().parse_known_args(args, namespace)
        if extras:
            self.error(f"unrecognized arguments: {' '.join(extras)}")
        return namespace, extras

    def error(self, message: str) -> NoReturn:
        what = " ".join(message.split())  # one line, whatever argparse composed
        self.exit(2, f"{self.prog}: error: {what} (see `{self.prog} --help`)\n")


def build_parser() -> argparse.ArgumentParser:
    """The whole command line in one parser; each command group registers its own subcommands."""
    parser = OneLineParser(prog="hystbench", description="The hystbench command line.")
    parser.add_argument("--version", action="version", version=f"hystbench {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    p = sub.add_parser("simulate", help="write one recording from the simulated rig")
    _add_rig_args(p)
    p.add_argument("--freq", type=positive_float, required=True, help="excitation frequency, Hz")
    p.add_argument("--ipp", type=float_in(0.0, SIM_MAX_IPP_A), required=True,
                   help=f"peak-to-peak current, A (at most {SIM_MAX_IPP_A:g})")
    p.add_argument("--out", type=path_arg, required=True, help="output stem (writes STEM.csv and STEM.json)")
    p.set_defaults(func=cmd_simulate)

    p = sub.add_parser("simulate-sweep", help="write a sweep folder from the simulated rig")
    _add_rig_args(p)
    p.add_argument("--freqs", type=positive_floats, default=[40, 80, 160, 320, 480], help="Hz, comma-separated")
    p.add_argument("--ipp", type=float_list_in(0.0, SIM_MAX_IPP_A), default=[1.4],
                   help=f"A-pp, comma-separated (each at most {SIM_MAX_IPP_A:g})")
    p.add_argument("--out", type=path_arg, required=True, help="output folder")
    p.set_defaults(func=cmd_simulate_sweep)

    p = sub.add_parser("effects", help="list the simulated rig's physical effects")
    p.set_defaults(func=cmd_effects)

    p = sub.add_parser("rigs", help="list rig presets with their force range at the operating point")
    p.add_argument("--json", action="store_true")
    p.set_defaults(func=cmd_rigs)

    p = sub.add_parser("force-map", help="static force map F(i, z) of an E-core (paper Fig. 3) as PNG")
    p.add_argument("--rig", default="ecore_pm", help="E-core preset (ecore, ecore_pm) or TOML path")
    p.add_argument("--out", type=path_arg, default="force_map.png")
    p.add_argument("--overwrite", action="store_true", help="replace an existing --out")
    p.set_defaults(func=cmd_force_map)

    p = sub.add_parser("fit-material", help="hysteresis model vs the real measured B-H loops (PNG + table)")
    p.add_argument("--out", type=path_arg, default="material-fit",
                   help="output folder (with --refit also the fitted TOML files)")
    p.add_argument("--refit", action="store_true",
                   help="fit again instead of using the shipped parameters; the material files go to --out "
                        "(the shipped ones are never rewritten)")
    p.add_argument("--overwrite", action="store_true", help="write into an existing, non-empty --out")
    p.add_argument("--json", action="store_true")
    p.set_defaults(func=cmd_fit_material)

    from . import bench as commands_bench, compensator as commands_compensator, method as commands_method, pipeline as commands_pipeline
    from . import bench_day as commands_bench_day

    commands_method.register(sub)  # estimate, identify, paper
    commands_bench.register(sub)  # emulate
    commands_pipeline.register(sub)  # watch, record, replay, export, recover, daemon
    commands_compensator.register(sub)  # model fit|predict, compensate
    commands_bench_day.register(sub)  # simulate-bench-day
    from . import diagnose as commands_diagnose

    commands_diagnose.register(sub)  # diagnose
    from . import router as commands_router

    commands_router.register(sub)  # router

    p = sub.add_parser("demo", help="the main job on the embedded simulated rig")
    p.add_argument("--out", type=path_arg, default="demo-output")
    p.add_argument("--overwrite", action="store_true", help="replace what an earlier demo wrote in --out")
    p.add_argument("--source", choices=("streams", "digitiser"), default="streams",
                   help="where the samples come from: the instruments' own frame streams, or one SCPI digitiser "
                        "(config/bench_digitiser.toml)")
    p.add_argument("--day", type=path_arg, default=None, metavar="DIR",
                   help="a bench day's folder to diagnose last (make demo: one of the independent bench's); "
                        "default: a concealed day of the simulated rig")
    p.add_argument("--baseline", type=commands_diagnose.effect_list("--baseline"), default=None, metavar="EFFECT,...",
                   help="with --day: the effects of your model of that bench (default: each rig preset's own)")
    p.add_argument("--truth", type=path_arg, default=None, metavar="FILE",
                   help="with --day: the generator's truth (JSON), printed after the verdict")
    p.set_defaults(func=cmd_demo)
    return parser


class _OneLineLog(logging.Handler):
    """Library warnings and errors as one line on stderr, without a traceback.  A logged
    BenchError is left out: the command raises it too, and main reports it once."""

    def __init__(self, command: str) -> None:
        super().__init__(logging.WARNING)
        self.command = command

    def emit(self, record: logging.LogRecord) -> None:
        err = record.exc_info[1] if record.exc_info else None
        if isinstance(err, BenchError):
            return
        try:
            why = f": {err}" if err is not None else ""
            print(f"hystbench {self.command}: {record.levelname.lower()}: {record.getMessage()}{why}",
                  file=sys.stderr, flush=True)
        except Exception:  # noqa: BLE001 - a log line must never take the command down
            pass


@contextmanager
def _one_line_logging(command: str) -> Iterator[None]:
    """Route the library's log through :class:`_OneLineLog` while the command runs (the daemon
    sets up its own log)."""
    logger = logging.getLogger("hystbench")
    handler = _OneLineLog(command) if command != "daemon" else None
    if handler is not None:
        logger.addHandler(handler)
    try:
        yield
    finally:
        if handler is not None:
            logger.removeHandler(handler)


def _line_buffered_stdout() -> None:
    """Line by line into a pipe (``hystbench ... | tee``), not in 8 kB lumps at the end."""
    try:
        sys.stdout.reconfigure(line_buffering=True)
    except (AttributeError, ValueError, OSError):
        pass


def _quiet_broken_pipe() -> None:
    """The reader went away (``| head``): point stdout at /dev/null so that the final flush at exit
    does not complain either."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
    except (AttributeError, ValueError, OSError):
        pass


def _one_line(message: str) -> str:
    """An error is one line, whatever a path in it holds (a file name may contain a newline)."""
    return message.replace("\r", "\\r").replace("\n", "\\n")


def _os_error_line(err: OSError) -> str:
    """``PATH: reason`` (the path first, as every other message names its file), not Python's
    ``[Errno 36] File name too long: 'PATH'``; an error with no path keeps its own text."""
    if err.filename is None:
        return str(err)
    paths = f"{err.filename}" + (f" -> {err.filename2}" if err.filename2 is not None else "")
    return f"{paths}: {err.strerror or err}"


def _exit_terminated(line: str) -> NoReturn:
    """Say it and exit 143 at once, as SIGTERM asked; the command has cleaned up by now.  Not through
    the interpreter's exit: an interrupt raised inside eval() (an import building a namedtuple) makes
    CPython 3.11 end by SIGINT there, caught or not (1 run in 30 exited -2, not 143)."""
    print(line, file=sys.stderr)
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):  # a closed pipe: nothing more to say there
            pass
    os._exit(143)


def main(argv: list[str] | None = None) -> int:
    """The ``hystbench`` command; returns the exit status.  Anything a user can trigger (a
    :class:`~hystbench.errors.BenchError`, a path the filesystem refuses) is one line on stderr and
    status 2, never a traceback."""
    _line_buffered_stdout()
    try:
        args = build_parser().parse_args(argv)
    except SystemExit as stop:  # --help, --version, or usage + one line naming the option (status 2)
        return stop.code if isinstance(stop.code, int) else 2
    where = f"hystbench {args.command}" + (f" {args.model_command}" if getattr(args, "model_command", None) else "")
    terminated: list[bool] = []
    try:
        # SIGTERM (``timeout``, a service manager) cleans up as Ctrl-C does: it killed a sweep half-way,
        # leaving its hidden folder; the daemon, the emulators and the router install their own handlers
        with _one_line_logging(args.command), noting(signal.SIGTERM) as terminated:
            code = args.func(args)
        if terminated:  # the interrupt fell in an import's callback, which swallows it: the command finished
            _exit_terminated(f"{where}: terminated (after the command finished: what it wrote is whole)")
        return code
    except BenchError as err:
        print(f"{where}: error: {_one_line(str(err))}", file=sys.stderr)
        return 2
    except BrokenPipeError:
        _quiet_broken_pipe()
        return 1
    except OSError as err:  # the filesystem refused a path the user gave (too long, not a folder, full disk)
        print(f"{where}: error: {_one_line(_os_error_line(err))}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:  # Ctrl-C: said, so that 130 is not read as a silent failure; SIGTERM: 128 + 15
        if terminated:
            _exit_terminated(f"{where}: terminated")
        print(f"{where}: interrupted", file=sys.stderr)
        return 130
