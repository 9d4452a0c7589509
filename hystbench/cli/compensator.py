"""Command-line wiring of the force models and the compensator (issue 6).

    hystbench model fit SWEEP_DIR --out MODEL.json
    hystbench model predict MODEL.json RECORDING --kind nonhysteretic|paper|best --out PRED.csv
    hystbench compensate --rig ecore_pm --force "offset=170,amp=40,freq=320" [--learn]

``register(subparsers)`` adds them; the CLI's ``main`` turns a BenchError into exit status 2.  The
work is the compensator's (:mod:`hystbench.compensator.sweeps`: recordings to period averages, the
identification on the simulated rig, a model's prediction for a recording), imported when a
command runs.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from ..errors import ConfigError
from .args import float_in, int_in, nonnegative_int, path_arg, positive_float

__all__ = ["register"]

#: Learning iterations a command may ask for: each plays a measurement on the bench (a few tenths of a
#: second and the settling); the loop reaches its noise floor in a few, so more is a typo, not a wish.
MAX_ITERATIONS = 200

#: The model kinds (``compensator.MODEL_KINDS``; repeated so that building the parser imports nothing).
MODEL_KINDS = ("nonhysteretic", "paper", "best")


def _json_out(obj) -> str:
    return json.dumps(obj, indent=2, default=lambda x: x.tolist() if isinstance(x, np.ndarray) else float(x))


def _console():
    from ..reports.console import console

    return console()


# --- hystbench model fit / predict ---------------------------------------------------------------
def cmd_model_fit(args: argparse.Namespace) -> int:
    """`hystbench model fit`: every force model fitted from one sweep into the one model file that
    ``model predict`` and ``compensate`` read (``--out`` is checked before the minutes of fitting)."""
    from ..compensator import MODEL_KINDS as KINDS, fit_models
    from ..compensator.sweeps import sweep_data
    from ..config import load_rig
    from ..reports.console import progress
    from ..formats.outputs import output_file
    from ..formats.recording import read_sweep

    unknown = [k for k in args.kinds if k not in KINDS]
    if unknown or not args.kinds:
        raise ConfigError(f"--kinds {','.join(args.kinds)!r}: choose from {', '.join(KINDS)}")
    # --out is checked (exists? a folder we can write in?) before the minutes of fitting
    inputs = [args.sweep] + ([args.instrument_sweep] if args.instrument_sweep is not None else [])
    with output_file(args.out, overwrite=args.overwrite, inputs=inputs) as tmp, progress() as bar:
        instrument = None
        if args.instrument_sweep is not None:
            from ..analysis.identification import fit_instrument, frequency_response

            instrument = fit_instrument(frequency_response(read_sweep(args.instrument_sweep, one_rig=True))).model
        recs = read_sweep(args.sweep, one_rig=True)  # one actuator's models: a bench day's folder is refused
        task = bar.add_task(f"period averages of {args.sweep}", total=len(recs))
        rig, points = sweep_data(recs, tick=lambda: bar.advance(task))
        bar.update(task, description=f"fitting {', '.join(args.kinds)}", total=None)
        models = fit_models(points, load_rig(rig), instrument, kinds=tuple(args.kinds),
                            tick=lambda: bar.update(task, description="fitting: judging the iron descriptions"))
        models.report["sweep"] = str(args.sweep)
        models.save(tmp, overwrite=True)
    path = Path(args.out)
    rows = models.report["training_error"]
    choice = models.report.get("choice", {})
    if args.json:
        print(_json_out({"model_file": str(path), "rig": rig, "training_error": rows,
                         "instrument": {"fn_Hz": models.instrument.fn_hz, "zeta_n": models.instrument.zeta_n},
                         "best_description": choice.get("chosen"), "why": choice.get("why"),
                         "held_out_worst_accuracy_pct": choice.get("worst_held_out_accuracy_pct"),
                         "held_out_largest_shortfall_pts": choice.get("largest_shortfall_pts")}))
        return 0
    from rich.table import Table

    table = Table(title=f"{rig}: force models fitted on {len(points)} recordings of {args.sweep}")
    table.add_column("recording", no_wrap=True)
    for kind in models.models:
        table.add_column(f"{kind} accuracy (%)", justify="right")
    for n, p in enumerate(points):
        table.add_row(Path(p.name).name, *(f"{rows[k][n]['accuracy_pct']:.3f}" for k in models.models))
    con = _console()
    con.print(table)
    if choice:
        held = Table(title="the best model's choice: every description on the recordings its fit did not see")
        for col in ("description", "worst held-out accuracy (%)", "largest shortfall from the best (points)", ""):
            held.add_column(col, justify="left" if not col or col == "description" else "right")
        for d, worst in choice["worst_held_out_accuracy_pct"].items():
            held.add_row(d, f"{worst:.3f}", f"{choice['largest_shortfall_pts'][d]:.3f}",
                         "chosen" if d == choice["chosen"] else "")
        for d, err in choice["failed"].items():
            held.add_row(d, "-", "-", f"failed: {err}")
        con.print(held)
        con.print(f"best model: {choice['why']}")
    con.print("accuracy = 100 % x (1 - max|F_measured - H_instr{F_model}| / force range) on the period average, on "
              f"the recordings fitted (judge on others with `model predict`). Wrote {path}")
    return 0


def cmd_model_predict(args: argparse.Namespace) -> int:
    """`hystbench model predict`: a model's force for a recording's current, as the load cell
    would report it, to set beside what the load cell measured."""
    from ..compensator import ModelSet
    from ..compensator.sweeps import predict_recording
    from ..formats.outputs import output_file
    from ..formats.recording import read_recording, recording_paths

    out = Path(args.out)
    rec_path = Path(args.recording)
    inputs = [args.model, *recording_paths(rec_path)]
    with output_file(out, overwrite=args.overwrite, inputs=inputs) as tmp:
        models = ModelSet.load(args.model)
        rec = read_recording(args.recording)
        t, f = predict_recording(models, rec, args.kind)
        np.savetxt(tmp, np.column_stack([t, f]), delimiter=",", header="time_s,force_N", comments="", fmt="%.12g")
    msg = f"wrote {out}: {t.size} samples, the {args.kind} model's force as the load cell would report it"
    if "force_N" in rec.channels:
        err = rec.channels["force_N"] - f
        msg += (f"; against the recording's force: rms {np.sqrt(np.mean(err ** 2)):.4g} N per sample (noise "
                "included; `model fit` and the benchmark report the period-averaged accuracy)")
    print(msg)
    return 0


# --- hystbench compensate -----------------------------------------------------------------------
def _reference(args):
    from ..compensator import ForceReference

    if args.force_file and args.force:  # the file was taken without a word, then failed as a shape
        raise ConfigError("--force and --force-file: give one force reference, not both")
    if args.force and args.freq is not None:  # it was ignored: --force names its own freq=
        raise ConfigError("--freq goes with --force-file; --force gives its frequency as freq=")
    if args.force_file:
        if args.freq is None:
            raise ConfigError("--force-file needs --freq (the frequency at which one table is one period)")
        return ForceReference.from_csv(args.force_file, args.freq)
    if not args.force:
        raise ConfigError("give --force \"offset=...,amp=...,freq=...\" or --force-file TABLE.csv --freq F")
    return ForceReference.parse(args.force)


def _precheck(rig: str, ref, limit_a: float) -> None:
    """Refuse at once (before any identification) what the static law already rules out: a
    negative force without a magnet, a force beyond what the current limit gives."""
    from ..compensator import StaticLaw
    from ..config import load_rig
    from ..drivers.protocols.bench_config import load_bench_config
    from ..physics import presets

    preset = load_rig(rig)
    if preset.get("actuator") != "ecore":
        raise ConfigError(f"--rig {rig!r} is a {preset.get('actuator')}, not an E-core")
    fs = load_bench_config().fs_hz
    if ref.highest_hz() >= fs / 2:  # it cannot be sampled, let alone measured (49.9 kHz was "tracked")
        raise ConfigError(f"force reference: it holds {ref.highest_hz():g} Hz, at or above half the bench's "
                          f"{fs:g} S/s; a compensator can neither play nor measure it")
    mec = presets.ecore_mec(preset, linear_iron=True)
    law = StaticLaw.from_coefficients(mec.force_coefficients(mec.geometry.airgap_m), "magnet" in preset)
    law.invert(ref.force_n, current_limit_a=limit_a)


def cmd_compensate(args: argparse.Namespace) -> int:
    """`hystbench compensate`: feed-forward force control of the simulated rig through the emulated
    instruments (``--direct``: the rig alone), with a model file or models identified on the rig first."""
    from contextlib import ExitStack

    from ..compensator import ModelSet
    from ..compensator.sweeps import FIT_GRID, quick_models
    from ..drivers.protocols.bench_config import load_bench_config
    from ..reports.console import progress
    from ..config.effects import parse_effect_args
    from ..sim_backend.bench_day import refuse_effects_not_acting

    ref = _reference(args)
    effects = parse_effect_args(args.effect)
    refuse_effects_not_acting(args.rig, effects)
    limit = args.max_current if args.max_current is not None else load_bench_config().current_limit_a
    _precheck(args.rig, ref, limit)
    con = _console() if not args.json else None
    if args.model:
        models = ModelSet.load(args.model)
        if models.rig != args.rig:
            raise ConfigError(f"{args.model}: models of {models.rig!r}, but --rig is {args.rig!r}")
        source = f"models from {args.model}"
    else:
        f_s, i_s = FIT_GRID
        with progress() as bar:
            task = bar.add_task(f"identifying the force models of {args.rig}", total=2 * len(f_s) * len(i_s))
            models = quick_models(args.rig, seed=args.seed + 1000, effects=effects, tick=lambda: bar.advance(task))
        source = (f"models identified on the simulated rig first: {len(f_s) * len(i_s)} recordings "
                  f"({', '.join(f'{f:g}' for f in f_s)} Hz x {min(i_s):g}-{max(i_s):g} A-pp)")
    with ExitStack() as stack:
        act = _actuation(args, stack, effects, ref, limit)
        return _closed_loop(args, act, models, source, ref, limit, con)


def _actuation(args, stack, effects, ref, limit):
    """The emulated instruments in front of a simulated rig, driven through the real drivers (the
    shipped bench file with the rig, seed and effects of the command line); ``--direct``: the rig
    alone.  Either way a bench just switched on: zero current, the iron demagnetised."""
    from ..compensator import BenchActuation, RigActuation
    from ..sim_backend.rig import SimulatedRig

    if args.direct:
        sim = SimulatedRig(args.rig, seed=args.seed, effects=effects, frequency_hz=ref.frequency_hz,
                           current_pp_a=0.0)
        return RigActuation(sim, limit)
    import dataclasses

    from ..drivers.bench import Bench
    from ..drivers.protocols.bench_config import load_bench_config
    from ..sim_backend.emulators.bench import EmulatedBench

    config = load_bench_config()
    config = dataclasses.replace(config, sim={**config.sim, "rig": args.rig, "seed": args.seed,
                                              "effects": {**config.sim["effects"], **effects}})
    emu = stack.enter_context(EmulatedBench(config))
    bench = stack.enter_context(Bench(config.resolved(emu.addresses)))
    return BenchActuation(bench, limit)


def _closed_loop(args, act, models, source, ref, limit, con) -> int:
    from ..compensator import LearningConfig, LearningStopped, run_closed_loop
    from ..reports.console import progress

    try:
        config = LearningConfig(gain=args.gain, iterations=args.iterations)
    except ValueError as err:  # the ranges the parser checks; this says which option if they drift apart
        raise ConfigError(f"--gain {args.gain:g} / --iterations {args.iterations}: {err}") from err
    rows: list[dict] = []
    bar = progress()
    task = bar.add_task("closed loop", total=1 + (config.iterations if args.learn else 0))

    def show(rep) -> None:
        bar.update(task, advance=1, description=f"closed loop: iteration {rep.iteration} done")
        rows.append(rep.as_dict())
        if con is not None:
            con.print(f"iteration {rep.iteration:2d}: max |dF| {rep.max_error_n:.4g} N ({rep.error_pct:.4f} % of the "
                      f"reference's range), noise floor {rep.noise_floor_n:.3g} N, ratio {rep.ratio:.2f}, "
                      f"peak current {rep.peak_current_a:.3f} A ({rep.status})")

    if con is not None:
        con.print(f"{args.rig}: {ref.description}; {args.kind} model, {source}; current limit {limit:g} A")
        con.print(f"driven through: {act.name}")
    try:
        with bar:
            result = run_closed_loop(act, models[args.kind], ref, models.instrument, learn=args.learn, config=config,
                                     measure_s=args.measure, on_iteration=show)
    except LearningStopped as err:
        if args.json:
            print(_json_out({"rig": args.rig, "reference": ref.description, "iterations": rows, "stopped": str(err),
                             "output_on": False}))
        raise
    act.output_off()
    summary = {"rig": args.rig, "reference": ref.description, "model": args.kind, "models_from": source,
               "learn": args.learn, "current_limit_A": limit, **result.as_dict(), "output_on": False,
               "driven_through": act.name}
    if args.json:
        print(_json_out(summary))
    else:
        reached = ("not reached" if result.reached_at is None else f"reached at iteration {result.reached_at}")
        con.print(f"tracking error within {config.target_ratio:g}x the noise floor of the averaged force: {reached}. "
                  "Error = max over the period-averaged force of |F_measured - H_instr{F_ref}|; noise floor = max of "
                  "the same average with alternating signs (the averaged noise of this record). Output off.")
    return 0


# --- wiring --------------------------------------------------------------------------------------
def register(subparsers: argparse._SubParsersAction) -> None:
    """Add ``model`` (``fit``, ``predict``) and ``compensate`` to the CLI's subparsers."""
    p = subparsers.add_parser("model", help="force models: fit from a sweep, predict a recording's force")
    sub = p.add_subparsers(dest="model_command", required=True, metavar="{fit,predict}")
    q = sub.add_parser("fit", help="fit every force model (Eq. 1, Eq. 6, ours) from a sweep folder")
    q.add_argument("sweep", type=path_arg, help="sweep folder of one E-core rig (NAME.csv + NAME.json per recording)")
    q.add_argument("--out", type=path_arg, required=True, help="model file to write (JSON)")
    q.add_argument("--kinds", type=lambda s: [k.strip() for k in s.split(",") if k.strip()],
                   default=list(MODEL_KINDS), help="comma-separated subset of " + ",".join(MODEL_KINDS))
    q.add_argument("--instrument-sweep", type=path_arg,
                   help="voice-coil sweep folder on the same load cell (paper Sec. IV): the force instrument is "
                        "fitted from it instead of taken from the rig preset")
    q.add_argument("--overwrite", action="store_true")
    q.add_argument("--json", action="store_true")
    q.set_defaults(func=cmd_model_fit)
    q = sub.add_parser("predict", help="the force a model predicts for a recording's current (as the load cell "
                                       "reports it)")
    q.add_argument("model", type=path_arg, help="model file from `hystbench model fit`")
    q.add_argument("recording", type=path_arg, help="recording (NAME.csv with NAME.json)")
    q.add_argument("--kind", choices=MODEL_KINDS, default="best")
    q.add_argument("--out", type=path_arg, required=True, help="CSV to write: time_s,force_N")
    q.add_argument("--overwrite", action="store_true")
    q.set_defaults(func=cmd_model_predict)

    p = subparsers.add_parser("compensate", help="feed-forward force control (and learning) on the simulated rig")
    p.add_argument("--rig", default="ecore_pm", help="E-core rig preset (default ecore_pm)")
    p.add_argument("--force", help='periodic force reference, e.g. "offset=170,amp=40,freq=320[,phase=0][,h2=5@90]"')
    p.add_argument("--force-file", type=path_arg, help="one period of force (CSV column force_N), with --freq")
    p.add_argument("--freq", type=positive_float, help="frequency of --force-file's period, Hz")
    p.add_argument("--learn", action="store_true", help="iterative learning on the measured force error")
    p.add_argument("--model", type=path_arg, help="model file (default: identify on the simulated rig first, ~5 s)")
    p.add_argument("--kind", choices=MODEL_KINDS, default="best", help="feed-forward model (default best)")
    p.add_argument("--iterations", type=int_in(0, MAX_ITERATIONS), default=10,
                   help=f"learning iterations, 0-{MAX_ITERATIONS} (default 10; the loop reaches its noise floor in a few)")
    p.add_argument("--gain", type=float_in(0.0, 1.5), default=0.8,
                   help="learning gain in (0, 1.5]; above 1 the error overshoots each iteration (default 0.8)")
    p.add_argument("--measure", type=float_in(0.0, 60.0), default=0.25,
                   help="seconds averaged per iteration, at most 60 (default 0.25)")
    p.add_argument("--max-current", type=positive_float, help="current limit, A (default: config/bench.toml)")
    p.add_argument("--effect", action="append", default=[], metavar="NAME=VALUE", help="simulated-rig effect switch")
    p.add_argument("--seed", type=nonnegative_int, default=0)
    p.add_argument("--direct", action="store_true",
                   help="drive the simulated rig directly instead of through the emulated instruments' drivers")
    p.add_argument("--json", action="store_true")
    p.set_defaults(func=cmd_compensate)
