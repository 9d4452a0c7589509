"""``hystbench simulate-bench-day``: a bench day of the simulated rigs, one sweep folder per rig.

The voice coil's stepped sine, then ``ecore`` and ``ecore_pm`` (issue 13's day), each rig running
on between its points, every recording's ``start_time_s`` on the day's one clock; the sidecars
hold what a real bench's hold (no effects, no seed).  Everything is simulated and checked (a
clipped channel, an existing file) before the first file is written.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any, Mapping

from ..errors import ConfigError, SimulationError
from .args import nonnegative_int, path_arg

__all__ = ["register", "cmd_simulate_bench_day", "refuse_clipped", "parse_rig_effects"]


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add ``simulate-bench-day`` to the CLI's subparsers."""
    p = subparsers.add_parser("simulate-bench-day", help="write a simulated bench day: one sweep folder per rig",
                              description="The voice coil's stepped sine, then ecore and ecore_pm, each rig running on "
                                          "between its points, every recording's start_time_s on the day's one "
                                          "clock; the sidecars hold what a real bench's hold (no effects, no "
                                          "seed). Everything is simulated and checked (a clipped channel, an "
                                          "existing file) before the first file is written.")
    p.add_argument("out", type=path_arg, help="output folder (OUT/voicecoil_ferrite, OUT/ecore, OUT/ecore_pm)")
    p.add_argument("--seed", type=nonnegative_int, default=0, help="noise seed (default 0)")
    p.add_argument("--bench", default=None, metavar="NAME",
                   help="a foreign bench (e.g. ecore_pm~m130; its E-cores share one core) instead of the presets")
    p.add_argument("--effect", action="append", default=[], metavar="[RIG:]NAME=VALUE",
                   help="switch an effect on one rig (RIG:NAME=on|off, RIG:NAME=<number>, RIG:NAME.param=<number>) "
                        "or, without RIG:, on every rig it acts on (repeatable)")
    p.add_argument("--quick", action="store_true", help="a short day (4 voice-coil points, 2 frequencies, 12 periods)")
    p.add_argument("--overwrite", action="store_true", help="replace existing recordings of the same name")
    p.set_defaults(func=cmd_simulate_bench_day)


def refuse_clipped(rec: Any) -> None:
    """A recording the ADC clipped is not a measurement: refused, naming the channel and the
    effect parameter to change (needs the generator's sidecar, with ``effects``)."""
    from ..sim_backend.recordings import clipped_by_noise, clipped_channels

    if rec.metadata.get("clipped"):
        why = []
        for ch, full in clipped_channels(rec).items():  # the advice follows the cause: noise or signal
            key, peak = ch.lower(), clipped_by_noise(rec, ch)
            if peak is None:
                why.append(f"{ch} (full scale ±{full:g}): the signal reaches it; lower --ipp (or --freq), or raise "
                           f"the full scale with --effect adc_quantisation.{key}=VALUE")
            else:
                sigma = rec.metadata["effects"]["sensor_noise"][key]
                why.append(f"{ch} (full scale ±{full:g}): the sensor noise does (rms {sigma:g}; the signal peaks at "
                           f"{peak:.3g}), not the current; lower it with --effect sensor_noise.{key}=VALUE, or "
                           f"raise the full scale with --effect adc_quantisation.{key}=VALUE")
        raise SimulationError(f"{rec.rig} at {rec.frequency_hz:g} Hz, {rec.current_pp_a:g} A-pp: the ADC clipped "
                              + ("; ".join(why) or "a channel"))


def _merge(a: Mapping[str, Any], b: Mapping[str, Any]) -> dict[str, Any]:
    """Effect tables ``b`` over ``a``; two parameter tables of one effect are merged."""
    out = dict(a)
    for name, v in b.items():
        out[name] = {**out[name], **v} if isinstance(v, Mapping) and isinstance(out.get(name), Mapping) else v
    return out


def parse_rig_effects(args: list[str], rigs: tuple[str, ...]) -> dict[str, dict[str, Any]]:
    """``--effect [RIG:]NAME...`` as per-rig effect tables: with RIG, for that rig; without, for every
    rig the effect acts on (:func:`~..sim_backend.bench_day.bench_effects`); each value parsed as
    ``simulate``'s ``--effect``."""
    from ..config.effects import parse_effect_args
    from ..sim_backend.bench_day import bench_effects, refuse_effects_not_acting

    wide: list[str] = []
    own: dict[str, list[str]] = {}
    for arg in args:
        rig, sep, rest = arg.partition(":")
        if not sep:
            wide.append(arg)
        elif rig not in rigs:
            raise ConfigError(f"--effect {arg!r}: no rig {rig!r} on this bench day; rigs: {', '.join(rigs)}")
        else:
            own.setdefault(rig, []).append(rest)
    spread = bench_effects(parse_effect_args(wide), rigs)
    mine = {r: parse_effect_args(own.get(r, [])) for r in rigs}
    for r in rigs:  # named for one rig, an effect must act on it (bench-wide ones go where they act)
        refuse_effects_not_acting(r, mine[r], f"--effect {r}")
    return {r: _merge(spread[r], mine[r]) for r in rigs}


def cmd_simulate_bench_day(args: argparse.Namespace) -> int:
    """`hystbench simulate-bench-day OUT`: a bench day as one sweep folder per rig under OUT."""
    from ..formats.outputs import output_folder
    from ..formats.recording import write_sweep
    from ..reports.console import progress as make_progress
    from ..sim_backend.bench_day import BenchDayPlan, public_metadata, simulate_bench_day

    plan = BenchDayPlan.quick() if args.quick else BenchDayPlan()
    effects = parse_rig_effects(args.effect, plan.rigs)
    out = Path(args.out)
    for rig in plan.rigs:  # before simulating, and before any folder is written
        if (out / rig).exists() and not (out / rig).is_dir():
            raise ConfigError(f"{args.out}: {out / rig} is a file; the day's {rig} sweep is a folder of that name")
    if not args.overwrite:
        for block in plan.blocks:
            for f, ipp in block.points:
                stem = out / block.rig / f"{block.rig}_{f:g}Hz_{ipp:g}App"
                for p in (stem.with_name(stem.name + ".csv"), stem.with_name(stem.name + ".json")):
                    if p.exists():
                        raise ConfigError(f"{args.out}: {p} exists; give --overwrite to replace it")
    total = sum(len(b.points) for b in plan.blocks)
    with make_progress() as progress:
        task = progress.add_task("simulating a bench day", total=total)
        recs = simulate_bench_day(plan, seed=args.seed, effects=effects, bench=args.bench, truth_in_sidecar=True,
                                  tick=lambda: progress.advance(task))
    for rec in recs:
        refuse_clipped(rec)
        rec.metadata = public_metadata(rec.metadata)
    days = {rig: [r for r in recs if r.rig == rig] for rig in plan.rigs}
    # the whole day or nothing (a full disk at the last rig left the first two), then what was written
    with output_folder(out, overwrite=True) as stage:  # what exists was refused above, unless --overwrite
        for rig, mine in days.items():
            write_sweep(mine, stage.path / rig, overwrite=True)
    for rig, mine in days.items():
        print(f"wrote {len(mine)} recordings to {out / rig} ({mine[0].start_time_s:.3f}-"
              f"{mine[-1].start_time_s + mine[-1].duration_s:.3f} s on the day's clock)")
    return 0
