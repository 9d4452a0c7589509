"""Command-line wiring of the pipeline: ``watch``, ``record``, ``replay``, ``export``, ``recover``,
``daemon``; and :func:`demo_live`, the live part of the demo.

``register(subparsers)`` adds the commands to the ``hystbench`` parser (whose ``main`` turns a
:class:`~hystbench.errors.BenchError` into exit status 2); ``python -m
hystbench.acquisition.commands_pipeline CMD ...`` runs them on their own.  The work is done in
the pipeline modules, imported when a command runs.
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path
from typing import Any, Callable

from ..errors import BenchError, RecordingError

__all__ = ["register", "record_log", "replay_log", "demo_live", "format_message"]

DEFAULT_CONNECT = "tcp/127.0.0.1:7447"


# --- record / replay (also used by tests and the demo) ---------------------------------------------
def _estimation_settings(cfg: dict | None) -> dict:
    e = dict((cfg or {}).get("estimation") or {})
    keys = ("periods", "hop_periods", "min_hop_s", "settle_periods", "max_fs_hz")
    return {k: float(e[k]) for k in keys if k in e}


def record_log(source, out: str | Path, *, estimation: dict | None = None, compression: str = "zstd",
               overwrite: bool = False, on_message: Callable[[str, dict], None] | None = None,
               timeout_s: float | None = None) -> dict:
    """Run ``source`` through the pipeline (no zenoh) into one MCAP log; returns a summary."""
    from .mcaplog import McapRecorder
    from .pipeline import Pipeline
    from .stages import WindowEstimator

    settings = {"periods": 10.0, "settle_periods": 2.0, **(estimation or {})}
    meta = {"recording": source.metadata(), "config": {"estimation": settings, "source": source.name}}
    rig = getattr(getattr(source, "rig", None), "preset", None)
    if rig:
        meta["rig"] = {k: v for k, v in rig.items() if not k.startswith("_")}
    est = WindowEstimator(source.fs_hz, source.metadata(), **settings)
    with McapRecorder(out, metadata=meta, compression=compression, overwrite=overwrite) as rec:
        pipe = Pipeline(source, estimator=est, recorder=rec)
        estimates = _run_collecting(pipe, on_message, timeout_s, f"{out}: recording failed")
    return {"log": [str(p) for p in rec.paths], "samples": pipe.stats["source"].samples, "estimates": estimates,
            "bytes": sum(Path(p).stat().st_size for p in rec.paths), "stats": pipe.stats_dict()}


def replay_log(path: str | Path, *, speed: str = "max", out: str | Path | None = None,
               on_message: Callable[[str, dict], None] | None = None, overwrite: bool = False) -> list[dict]:
    """Feed a log through the same pipeline (estimation settings from the log); the estimates.
    With ``out``, the replay is itself recorded."""
    from .mcaplog import McapSource
    from .pipeline import Pipeline
    from .stages import WindowEstimator

    src = McapSource(path, pace="realtime" if speed == "realtime" else "max")
    if out is not None:
        return record_log(src, out, estimation=_estimation_settings(src.config), overwrite=overwrite,
                          on_message=on_message)["estimates"]
    est = WindowEstimator(src.fs_hz, src.metadata(), **_estimation_settings(src.config))
    pipe = Pipeline(src, estimator=est, dtype=src.dtype)
    return _run_collecting(pipe, on_message, None, f"{path}: replay failed")


def _run_collecting(pipe, on_message, timeout_s: float | None, failure: str) -> list[dict]:
    """Run the pipeline to its end (Ctrl-C or ``timeout_s`` stop it); its estimates, in order."""
    estimates: list[dict] = []
    pipe.listeners.append(lambda t, o: estimates.append(dict(o)) if t == "/estimate" else None)
    if on_message is not None:
        pipe.listeners.append(on_message)
    pipe.start()
    try:
        if not pipe.join(timeout_s):
            pipe.stop()
    except KeyboardInterrupt:
        pipe.stop()
    if pipe.error is not None:
        raise BenchError(f"{failure}: {pipe.error}") from pipe.error
    return estimates


# --- printing ------------------------------------------------------------------------------------------
def _is_raw(keyexpr: str) -> bool:
    parts = keyexpr.split("/")
    return len(parts) >= 3 and parts[2] == "raw"


def format_message(keyexpr: str, payload: bytes) -> str:
    """One line for one zenoh sample (estimate, status, stats, raw block, anything JSON)."""
    if _is_raw(keyexpr):
        from .zenoh_bus import decode_raw

        b = decode_raw(payload)
        parts = [f"{c} mean {float(x.mean()):.6g} rms {float((x.astype(float) ** 2).mean()) ** 0.5:.6g}"
                 for c, x in b.channels.items()]
        return f"{keyexpr} [{b.first_index}..{b.end_index}) " + "; ".join(parts)
    try:
        obj = json.loads(payload)
    except ValueError:
        return f"{keyexpr} {len(payload)} bytes"
    if keyexpr.rsplit("/", 1)[-1] == "estimate":
        if obj.get("error"):
            return f"{keyexpr} [{obj['first_index']}..{obj['end_index']}) error: {obj['error']}"
        ph = " ".join(f"{k} {v:.4f} deg" for k, v in (obj.get("phases_deg") or {}).items())
        return (f"{keyexpr} [{obj['first_index']}..{obj['end_index']}) f {obj.get('frequency_Hz', 0):.4f} Hz "
                f"{obj.get('current_pp_A', 0):g} A-pp: {ph}")
    if keyexpr.rsplit("/", 1)[-1] == "status":
        return f"{keyexpr} {obj.get('level')} {obj.get('event')}: {obj.get('message', '')}"
    return f"{keyexpr} {json.dumps(obj, separators=(',', ':'))[:300]}"


# --- commands ----------------------------------------------------------------------------------------
def cmd_watch(args) -> int:
    from .zenoh_bus import Subscription, load_zenoh_config, open_session

    connect = args.connect or ([] if args.zenoh_config else [DEFAULT_CONNECT])
    cfg = load_zenoh_config(args.zenoh_config, listen=[] if not args.zenoh_config else None,
                            connect=connect or None)
    session = open_session(cfg)
    sub = Subscription(session, args.keyexpr)
    n = 0
    try:
        for key_, payload, _ in sub.iter(count=args.count, seconds=args.seconds):
            line = json.dumps({"key": key_, **json.loads(payload)}) if args.json and not _is_raw(key_) \
                else format_message(key_, payload)
            print(line, flush=True)
            n += 1
    except KeyboardInterrupt:
        pass
    finally:
        sub.close()
        session.close()
    if args.count is not None and n < args.count:
        print(f"hystbench watch: {n} of {args.count} messages on {args.keyexpr} before the time ran out",
              file=sys.stderr)
        return 1
    return 0


def _source_from_args(args):
    from .sources import RigSource, SyntheticSource

    if args.source == "synthetic":
        return SyntheticSource(fs_hz=args.fs, frequency_hz=args.freq, block_samples=args.block, pace=args.pace,
                               duration_s=args.seconds, rig=args.rig, current_pp_a=args.ipp, seed=args.seed)
    if args.source == "bench":
        from .sources import bench_source

        src = bench_source(args.bench_file, rig=args.rig, duration_s=args.seconds)
        src.set_excitation(frequency_hz=args.freq, current_pp_a=args.ipp)
        src.set_output(True)
        return src
    from ..sim_backend.effects import parse_effect_args
    from ..sim_backend.rig import SimulatedRig

    rig = SimulatedRig(args.rig, fs_hz=args.fs, seed=args.seed, effects=parse_effect_args(args.effect),
                       frequency_hz=args.freq, current_pp_a=args.ipp)
    return RigSource(rig, block_samples=args.block, pace=args.pace, duration_s=args.seconds)


def _print_estimate(topic: str, obj: dict) -> None:
    if topic == "/estimate":
        print(format_message("estimate", json.dumps(obj).encode()), flush=True)


def cmd_record(args) -> int:
    src = _source_from_args(args)
    try:
        res = record_log(src, args.out, compression=args.compression, overwrite=args.overwrite,
                         on_message=_print_estimate if args.verbose else None)
    finally:
        src.close()
    errs = sum(1 for e in res["estimates"] if e.get("error"))
    print(f"wrote {', '.join(res['log'])}: {res['samples']} samples x {len(src.channels)} channels, "
          f"{len(res['estimates'])} estimates ({errs} refused), {res['bytes'] / 1e6:.2f} MB")
    return 0


def cmd_replay(args) -> int:
    ests = replay_log(args.log, speed=args.speed, out=args.out, overwrite=args.overwrite,
                      on_message=None if args.json else _print_estimate)
    if args.json:
        print(json.dumps(ests, indent=2))
    else:
        print(f"{len(ests)} estimates from {args.log}")
    return 0


def cmd_export(args) -> int:
    from .mcaplog import read_mcap_segments
    from .recording import sweep_stem, write_recording

    recs = read_mcap_segments(args.log, include_idle=args.include_idle)
    out = Path(args.out)
    stems: list[str] = []
    for k, rec in enumerate(recs):
        stem = sweep_stem(rec)
        if stem in stems:
            stem = f"{stem}_seg{k}"
        stems.append(stem)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise RecordingError(f"{out}: cannot create the folder: {err.strerror}") from err
    for rec, stem in zip(recs, stems):
        csv_path, _ = write_recording(rec, out / stem, overwrite=args.overwrite)
        print(f"wrote {csv_path} ({rec.n} samples at {rec.fs_hz:g} Hz, {rec.frequency_hz:g} Hz, "
              f"{rec.current_pp_a:g} A-pp)")
    return 0


def cmd_recover(args) -> int:
    from .mcaplog import recover

    rep = recover(args.log, args.out, overwrite=args.overwrite)
    if args.json:
        print(json.dumps(rep.as_dict(), indent=2))
    else:
        d = rep.as_dict()
        why = "the log was complete" if rep.complete else f"stopped: {rep.stopped}"
        print(f"wrote {rep.out}: {rep.messages} messages from {rep.chunks} chunks "
              f"({', '.join(f'{k} {v}' for k, v in sorted(d['by_topic'].items()))}); "
              f"{d['bytes_lost']} of {d['bytes_total']} bytes not salvaged ({why})")
    return 0


def cmd_daemon(args) -> int:
    from .daemon import run_daemon

    return run_daemon(args.config)


def register(subparsers) -> None:
    """Add watch, record, replay, export, recover and daemon to the ``hystbench`` parser."""
    p = subparsers.add_parser("watch", help="print live messages of a bench from zenoh (estimates by default)")
    p.add_argument("keyexpr", nargs="?", default="hystbench/*/estimate",
                   help="zenoh key expression (default hystbench/*/estimate; e.g. hystbench/bench1/**)")
    p.add_argument("--connect", action="append", metavar="ENDPOINT",
                   help=f"endpoint of the daemon (default {DEFAULT_CONNECT}; repeatable)")
    p.add_argument("--zenoh-config", metavar="FILE", help="zenoh json5 config (e.g. with user/password or TLS)")
    p.add_argument("--count", type=int, help="stop after N messages (exit 1 if fewer came in --seconds)")
    p.add_argument("--seconds", type=float, help="stop after S seconds")
    p.add_argument("--json", action="store_true", help="one JSON object per line")
    p.set_defaults(func=cmd_watch)

    p = subparsers.add_parser("record", help="record the configured source to an MCAP log (no daemon)")
    p.add_argument("--out", required=True, help="the log, e.g. run.mcap")
    p.add_argument("--seconds", type=float, default=2.0, help="how long (default 2)")
    p.add_argument("--source", choices=("bench", "sim", "synthetic"), default="bench",
                   help="bench (default): the instruments of --bench-file through the drivers, emulated when the "
                        "file says backend = \"sim\" (the shipped one does); sim: the simulated rig directly; "
                        "synthetic: precomputed sines")
    p.add_argument("--bench-file", help="bench file for --source bench (default: hystbench/config/bench.toml)")
    p.add_argument("--rig", default="ecore_pm")
    p.add_argument("--freq", type=float, default=320.0, help="excitation frequency, Hz (default 320)")
    p.add_argument("--ipp", type=float, default=1.4, help="peak-to-peak current, A (default 1.4)")
    p.add_argument("--fs", type=float, default=100_000.0, help="sample rate, Hz (default 100000)")
    p.add_argument("--block", type=int, default=1000, help="samples per source block (default 1000)")
    p.add_argument("--pace", choices=("realtime", "max"), default="realtime")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--effect", action="append", default=[], metavar="NAME=VALUE")
    p.add_argument("--compression", choices=("zstd", "lz4", "none"), default="zstd")
    p.add_argument("--overwrite", action="store_true")
    p.add_argument("--verbose", "-v", action="store_true", help="print each estimate")
    p.set_defaults(func=cmd_record)

    p = subparsers.add_parser("replay", help="feed an MCAP log through the pipeline again")
    p.add_argument("log")
    p.add_argument("--speed", choices=("realtime", "max"), default="max")
    p.add_argument("--out", help="record the replay (with its estimates) to this log")
    p.add_argument("--overwrite", action="store_true")
    p.add_argument("--json", action="store_true", help="print the estimates as JSON")
    p.set_defaults(func=cmd_replay)

    p = subparsers.add_parser("export", help="write an MCAP log's segments as interchange-format recordings")
    p.add_argument("log")
    p.add_argument("--out", required=True, help="output folder")
    p.add_argument("--include-idle", action="store_true", help="also segments with the output off")
    p.add_argument("--overwrite", action="store_true")
    p.set_defaults(func=cmd_export)

    p = subparsers.add_parser("recover", help="salvage the complete chunks of a log whose writer was killed")
    p.add_argument("log")
    p.add_argument("--out", help="the salvaged log (default LOG-recovered.mcap)")
    p.add_argument("--overwrite", action="store_true")
    p.add_argument("--json", action="store_true")
    p.set_defaults(func=cmd_recover)

    p = subparsers.add_parser("daemon", help="run the bench daemon (systemd-ready; SIGHUP reloads)")
    p.add_argument("--config", help="daemon TOML (default: built-in defaults, the simulated rig)")
    p.set_defaults(func=cmd_daemon)


def demo_live(out_dir: str | Path, seconds: float = 6.0, source: str = "bench") -> dict[str, Any]:
    """The daemon's pipeline in-process: a short sweep through the emulated instruments' drivers
    (``source="bench"``; ``"sim"``: the simulated rig directly), its live estimates printed as they
    arrive over zenoh (an ephemeral port on 127.0.0.1), an MCAP log in ``out_dir``."""
    from .daemon import BenchService, load_daemon_config
    from .zenoh_bus import Subscription, free_port, key, load_zenoh_config, open_session

    out = Path(out_dir)
    port = free_port()
    freqs = [80.0, 160.0, 320.0]
    toml = out / "demo-daemon.toml"
    out.mkdir(parents=True, exist_ok=True)
    toml.write_text(f'[daemon]\nbench = "demo"\nlog_dir = "{out.as_posix()}"\n[source]\nkind = "{source}"\n'
                    f'[zenoh]\nlisten = ["tcp/127.0.0.1:{port}"]\n'
                    f'[sweep]\nfrequencies_hz = {freqs}\ndwell_s = {max(seconds / len(freqs), 0.5):g}\n'
                    f'autostart = true\n', encoding="utf-8")
    svc = BenchService(load_daemon_config(toml)).start()
    watcher = open_session(load_zenoh_config(None, connect=[f"tcp/127.0.0.1:{port}"]))
    sub = Subscription(watcher, key("demo", "estimate"))
    got: list[dict] = []
    t_end = time.monotonic() + len(freqs) * max(seconds / len(freqs), 0.5) + 0.5
    try:
        for k, payload, _ in sub.iter(seconds=max(0.0, t_end - time.monotonic())):
            got.append(json.loads(payload))
            print(format_message(k, payload), flush=True)
    finally:
        sub.close()
        watcher.close()
        paths = svc.stop()
    good = [e for e in got if not e.get("error")]
    by_f: dict[float, list] = {}
    for e in good:
        by_f.setdefault(e["nominal_frequency_Hz"], []).append(e["phases_deg"].get("hysteresis"))
    return {"log": [str(p) for p in paths], "estimates": len(got), "refused": len(got) - len(good),
            "hysteresis_deg": {f"{f:g}": sum(v) / len(v) for f, v in sorted(by_f.items()) if v}}


