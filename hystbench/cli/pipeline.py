"""Command-line wiring of the pipeline: ``watch``, ``ctl``, ``record``, ``replay``, ``export``,
``recover``, ``daemon``.

``register(subparsers)`` adds the commands to the ``hystbench`` parser (whose ``main`` turns a
:class:`~hystbench.errors.BenchError` into exit status 2).  The work is done in the library
(``acquisition.record`` records and replays, ``service.control`` talks to a daemon), imported
when a command runs; :func:`format_message` is how a message is printed on the terminal.
"""

from __future__ import annotations

import argparse
import json
import signal
import sys
from pathlib import Path
from typing import Any, Callable, Iterator

from ..deadline import Deadline
from ..errors import BenchError, RecordingError
from .signals import noting

__all__ = ["register", "format_message"]

DEFAULT_CONNECT = "tcp/127.0.0.1:7447"
_MAX_TIMEOUT_S = 86_400.0  # service.control.MAX_TIMEOUT_S (not imported here: it loads zenoh)
#: the longest ``record`` runs, s (about 30 years): a bound, so that seconds x rate stays a count of
#: samples (1e308 s was "cannot convert float infinity to integer"); the daemon is for open-ended runs
MAX_RECORD_S = 1e9
MAX_BLOCK_SAMPLES = 1_000_000  # acquisition.sources.MAX_BLOCK_SAMPLES (not imported here: it loads numpy)


# --- printing ------------------------------------------------------------------------------------------
def _is_raw(keyexpr: str) -> bool:
    parts = keyexpr.split("/")
    return len(parts) >= 3 and parts[2] == "raw"


def format_message(keyexpr: str, payload: bytes) -> str:
    """One line for one zenoh sample (estimate, status, stats, raw block, anything JSON)."""
    if _is_raw(keyexpr):
        from ..formats.raw_block import decode

        b = decode(payload, keyexpr)
        parts = [f"{c} mean {float(x.mean()):.6g} rms {float((x.astype(float) ** 2).mean()) ** 0.5:.6g}"
                 for c, x in b.channels.items()]
        p = b.point
        at = "" if p is None else f" {p.frequency_hz:g} Hz {p.current_pp_a:g} A-pp" + (
            " off" if not p.output_on else " settling" if p.settling else "")
        return f"{keyexpr} [{b.first_index}..{b.end_index}){at} " + "; ".join(parts)
    try:
        obj = json.loads(payload)
    except ValueError:
        return f"{keyexpr} {len(payload)} bytes"
    if keyexpr.rsplit("/", 1)[-1] == "estimate":
        from ..messages import Estimate

        try:
            e = Estimate.from_json(obj)
        except BenchError:  # not an estimate this version knows: shown as it came
            return f"{keyexpr} {json.dumps(obj, separators=(',', ':'))[:300]}"
        span = f"{keyexpr} [{e.first_index}..{e.end_index})"
        if e.error:
            return f"{span} error: {e.error}"
        ph = " ".join(f"{k} {v:.4f} deg" for k, v in e.phases_deg.items())
        return f"{span} f {e.frequency_hz:.4f} Hz {e.current_pp_a:g} A-pp: {ph}"
    if keyexpr.rsplit("/", 1)[-1] == "status":
        return f"{keyexpr} {obj.get('level')} {obj.get('event')}: {obj.get('message', '')}"
    return f"{keyexpr} {json.dumps(obj, separators=(',', ':'))[:300]}"


# --- commands ----------------------------------------------------------------------------------------
def _watch_items(sub, keyexpr: str, endpoint: str, *, count: int | None, seconds: float | None,
                 quiet_after_s: float) -> Iterator[tuple[str, bytes]]:
    """The samples of ``sub`` until ``count`` or ``seconds``; when nothing has arrived for
    ``quiet_after_s`` (0: never), says so once on stderr and keeps waiting (said again only after
    a message came and the line went quiet again)."""
    deadline = Deadline(seconds)
    quiet = Deadline(quiet_after_s)  # since the start, then since the last message
    warned = not quiet_after_s > 0
    got = 0
    while count is None or got < count:
        if not warned and quiet.expired:  # before the deadline test: said even at the end
            what = "no publisher seen" if got == 0 else "no message"
            print(f"hystbench watch: {what} on {keyexpr} via {endpoint} for {quiet.elapsed:.1f} s (is the daemon "
                  "running, with that bench name and endpoint?); still waiting", file=sys.stderr, flush=True)
            warned = True
        if deadline.expired:
            return
        item = sub.get(deadline.left(0.2) if warned else min(deadline.left(0.2), quiet.left()))
        if item is not None:
            got += 1
            quiet = Deadline(quiet_after_s)
            warned = not quiet_after_s > 0
            yield item[0], item[1]


def cmd_watch(args: argparse.Namespace) -> int:
    """`hystbench watch`: a bench's live messages from zenoh, one line each (estimates by default),
    for a person or a pipe."""
    from ..acquisition.zenoh_bus import Subscription
    from ..service.control import describe_endpoint, open_client

    session = open_client(args.connect, args.zenoh_config)
    sub = Subscription(session, args.keyexpr)
    endpoint = describe_endpoint(args.connect, args.zenoh_config)
    n, stopped = 0, False
    try:
        for key_, payload in _watch_items(sub, args.keyexpr, endpoint,
                                          count=args.count, seconds=args.seconds, quiet_after_s=args.quiet_after):
            line = json.dumps({"key": key_, **json.loads(payload)}) if args.json and not _is_raw(key_) \
                else format_message(key_, payload)
            print(line, flush=True)
            n += 1
    except KeyboardInterrupt:  # the usual way to end a watch: not a failure
        stopped = True
    finally:
        sub.close()
        session.close()
    if n == 0 and not stopped:  # the time ran out on silence: a script must not read that as success
        print(f"hystbench watch: nothing received on {args.keyexpr} via {endpoint} in {args.seconds:g} s",
              file=sys.stderr)
        return 1
    if args.count is not None and n < args.count:
        print(f"hystbench watch: {n} of {args.count} messages on {args.keyexpr} before the time ran out",
              file=sys.stderr)
        return 1
    return 0


# --- ctl: a running daemon's commands and queries ---------------------------------------------------
def _ctl_payload(args) -> dict[str, Any]:
    """The JSON arguments of ``args.verb`` (only what was given: the daemon fills in the rest)."""
    named = {"start_sweep": (("frequencies_hz", "freqs"), ("current_pp_a", "ipp"), ("dwell_s", "dwell")),
             "set_excitation": (("frequency_hz", "freq"), ("current_pp_a", "ipp"), ("offset_a", "offset"))}
    if args.verb == "output":
        return {"on": args.state == "on"}
    payload = {k: getattr(args, opt) for k, opt in named.get(args.verb, ()) if getattr(args, opt) is not None}
    if args.verb == "set_excitation" and not payload:
        from ..errors import ConfigError

        raise ConfigError("set_excitation: give at least one of --freq, --ipp, --offset")
    return payload


def _format_reply(bench: str, verb: str, reply: dict) -> str:
    if verb == "config":
        return json.dumps(reply, indent=2)
    if verb == "health":
        return "\n".join(f"{k}: {v}" for k, v in reply.items())
    if verb == "status":
        on = reply.get("output_on")
        output = f"output {'on' if on else 'off' if on is False else 'unknown'}"
        if all(isinstance(reply.get(k), (int, float)) for k in ("frequency_hz", "current_pp_a", "offset_a")):
            output += (f" at {reply['frequency_hz']:g} Hz, {reply['current_pp_a']:g} A-pp, offset "
                       f"{reply['offset_a']:g} A" + (" (commanded)" if reply.get("as_of") == "commanded" else ""))
        parts = [f"{reply.get('state', '?')}", output, f"source {reply.get('source', '?')}"]
        if isinstance(reply.get("uptime_s"), (int, float)):
            parts.append(f"up {reply['uptime_s']:.0f} s")
        parts += [f"{reply.get('samples', 0)} samples", f"{reply.get('estimates', 0)} estimates",
                  f"log {reply.get('log') or '(none)'}"]
        parts += [f"{k} {reply[k]}" for k in ("output_refused", "last_fault", "pipeline_error", "last_estimate_error")
                  if reply.get(k)]
        return f"{bench}: " + "; ".join(parts)
    rest = ", ".join(f"{k} {json.dumps(v)}" for k, v in reply.items() if k != "ok")
    return f"{bench}: {verb} ok" + (f" ({rest})" if rest else "")


def cmd_ctl(args: argparse.Namespace) -> int:
    """One command or query to a running daemon; exit 1 if it refuses (its reason on stderr),
    2 if nobody answers within ``--timeout``."""
    from ..errors import CommandRefused
    from ..service.control import BenchControl, is_bench_pattern

    if is_bench_pattern(args.bench):
        return _ctl_fleet(args)
    payload = _ctl_payload(args)
    with BenchControl(args.bench, connect=args.connect, zenoh_config=args.zenoh_config,
                      timeout_s=args.timeout) as ctl:
        try:
            reply = ctl.request("health" if args.verb == "status" else args.verb, payload)
        except CommandRefused as err:
            if args.json:
                print(json.dumps(err.reply), flush=True)
            print(f"hystbench ctl: {err}", file=sys.stderr)
            return 1
    print(json.dumps(reply) if args.json else _format_reply(args.bench, args.verb, reply), flush=True)
    return 0


def _ctl_fleet(args: argparse.Namespace) -> int:
    """``ctl --bench PATTERN status|health``: every bench that answers within ``--timeout``, one line
    each (with ``--json`` one object each), sorted by name; exit 0 when at least one answered, 2
    when none did.  Commands go to one bench only: refused in one line, nothing sent."""
    from ..errors import ConfigError, NoReply
    from ..service.control import FLEET_VERBS, describe_endpoint, fleet_health, open_client

    if args.verb not in FLEET_VERBS:
        raise ConfigError(f"--bench {args.bench!r} names several benches: only {' and '.join(FLEET_VERBS)} may go to "
                          f"several; {args.verb} goes to one bench (--bench NAME)")
    session = open_client(args.connect, args.zenoh_config)
    try:
        benches = fleet_health(args.bench, session, timeout_s=args.timeout)
    finally:
        session.close()
    endpoint = describe_endpoint(args.connect, args.zenoh_config)
    if not any(h is not None for h in benches.values()):
        raise NoReply(f"no daemon answered on hystbench/{args.bench}/health via {endpoint} within {args.timeout:g} s")
    for bench, h in benches.items():
        if h is None:
            print(json.dumps({"bench": bench, "ok": False, "error": "alive, no health reply"}) if args.json else
                  f"{bench}: alive, but no health reply within {args.timeout:g} s", flush=True)
        elif args.json:
            print(json.dumps({"bench": bench, **h}), flush=True)
        elif args.verb == "health":
            print(f"{bench}: " + "; ".join(f"{k} {json.dumps(v)}" for k, v in h.items() if k != "bench"), flush=True)
        else:
            issues = any(h.get(k) for k in ("output_refused", "last_fault", "pipeline_error", "last_estimate_error"))
            print(_format_reply(bench, "status", h) + ("" if issues else "; healthy"), flush=True)
    return 0


def _keyexpr(text: str) -> str:
    """A zenoh key expression (``hystbench/*/estimate``), checked by zenoh itself while parsing."""
    import argparse

    import zenoh

    try:
        zenoh.KeyExpr(text)
    except zenoh.ZError:
        raise argparse.ArgumentTypeError(f"must be a zenoh key expression such as hystbench/*/estimate (chunks "
                                         f"separated by single /, none empty), got {text!r}") from None
    return text


def _register_ctl(subparsers) -> None:
    import argparse

    from .args import finite_float, float_in, nonnegative_float, path_arg, positive_float, positive_floats

    def client_options(p, top: bool) -> None:
        keep = (lambda v: v) if top else (lambda v: argparse.SUPPRESS)  # given after the verb: still taken
        p.add_argument("--bench", default=keep("bench1"),
                       help="the daemon's [daemon] bench (default bench1); '*' (or 'lab-*'): every bench reached, "
                            "for status and health only")
        p.add_argument("--connect", action="append", metavar="ENDPOINT", default=keep(None),
                       help=f"endpoint of the daemon (default {DEFAULT_CONNECT}; repeatable)")
        p.add_argument("--zenoh-config", metavar="FILE", type=path_arg, default=keep(None),
                       help="zenoh json5 config (e.g. with user/password or TLS)")
        p.add_argument("--timeout", type=float_in(0.0, _MAX_TIMEOUT_S), default=keep(2.0), metavar="S",
                       help=f"give up when no daemon answered within S seconds, at most {_MAX_TIMEOUT_S:g} "
                            "(exit 2; default 2)")
        p.add_argument("--json", action="store_true", default=keep(False), help="print the reply as JSON")

    p = subparsers.add_parser("ctl", help="drive a running daemon: output, sweeps, excitation, status, health, config",
                              description="Send one command (or query) to a running `hystbench daemon` over zenoh "
                                          "and print its reply. Exit 0: done; 1: the daemon refused (its reason on "
                                          "stderr); 2: bad arguments, or no daemon answered.")
    client_options(p, top=True)
    verbs = p.add_subparsers(dest="verb", required=True, metavar="VERB")
    shared = argparse.ArgumentParser(add_help=False)
    client_options(shared, top=False)
    v = verbs.add_parser("output", parents=[shared], help="generator output on or off")
    v.add_argument("state", choices=("on", "off"))
    v = verbs.add_parser("start_sweep", parents=[shared], help="run a sweep (defaults: the daemon's [sweep])")
    v.add_argument("--freqs", type=positive_floats, metavar="F1,F2,...", help="frequencies, Hz, comma-separated")
    v.add_argument("--ipp", type=nonnegative_float, help="peak-to-peak current, A")
    v.add_argument("--dwell", type=positive_float, metavar="S", help="seconds at each frequency")
    verbs.add_parser("stop_sweep", parents=[shared], help="stop the sweep, output off")
    verbs.add_parser("clear_fault", parents=[shared], help="after the excitation tripped the bench: allow output on "
                                                           "again (status says why it is refused)")
    v = verbs.add_parser("set_excitation", parents=[shared], help="change the excitation (any of its parts)")
    v.add_argument("--freq", type=positive_float, help="frequency, Hz")
    v.add_argument("--ipp", type=nonnegative_float, help="peak-to-peak current, A")
    v.add_argument("--offset", type=finite_float, help="DC offset, A")
    verbs.add_parser("status", parents=[shared], help="one line: state, output on/off with its frequency, current and "
                                                      "offset, source, samples, estimates, log")
    verbs.add_parser("health", parents=[shared], help="the health queryable, every field")
    verbs.add_parser("config", parents=[shared], help="the running configuration (JSON)")
    p.set_defaults(func=cmd_ctl)


#: The rig of --source sim and synthetic when --rig is not given.
DEFAULT_RIG = "ecore_pm"

#: The record options each source takes beyond --seconds, --freq and --ipp (the rest would be
#: ignored without a word: `--source bench --fs 50000` recorded at the bench file's 100 kHz)
_RECORD_OPTIONS = {"bench": {"bench_file", "rig"}, "sim": {"rig", "fs", "block", "pace", "seed", "effect"},
                   "synthetic": {"rig", "fs", "block", "pace", "seed"}, "zenoh": {"bench", "connect", "zenoh_config"}}

_RECORD_KEYS = sorted(set().union(*_RECORD_OPTIONS.values()))


def _check_record_options(args) -> None:
    """Refuse, by option, what the chosen source would ignore."""
    from ..errors import ConfigError

    ignored = [k for k in _RECORD_KEYS  # each against the parser's own default (given or not)
               if k not in _RECORD_OPTIONS[args.source] and getattr(args, k) != args.record_defaults[k]]
    if ignored:
        opts = ", ".join("--" + k.replace("_", "-") for k in ignored)
        where = {"bench": "the bench file sets them ([bench] fs_hz, [sim] block_samples, pace, seed and effects)",
                 "zenoh": "the daemon's configuration sets them"}.get(args.source, "it has no such setting")
        raise ConfigError(f"{opts}: not taken by --source {args.source}; {where}")


def _source_from_args(args):
    from ..acquisition.sources import RigSource, SyntheticSource

    _check_record_options(args)
    if args.source == "zenoh":
        from ..acquisition.zenoh_source import ZenohSource
        from ..service.control import client_config

        return ZenohSource(args.bench, client_config(args.connect, args.zenoh_config), duration_s=args.seconds)

    if args.source == "synthetic":
        return SyntheticSource(fs_hz=args.fs, frequency_hz=args.freq, block_samples=args.block, pace=args.pace,
                               duration_s=args.seconds, rig=args.rig or DEFAULT_RIG, current_pp_a=args.ipp,
                               seed=args.seed)
    if args.source == "bench":
        from ..acquisition.sources import bench_source

        # --rig: the emulated rig behind the instruments (a bench file with hardware refuses it, naming it)
        if args.rig:
            from ..errors import ConfigError
            from ..sim_backend.emulators.bench import missing_channels

            if missing := missing_channels(args.rig):
                raise ConfigError(f"--rig: {missing}; record it with --source sim")
        src = bench_source(args.bench_file, duration_s=args.seconds, sim={"rig": args.rig} if args.rig else None)
        src.set_excitation(frequency_hz=args.freq, current_pp_a=args.ipp)
        src.set_output(True)
        return src
    from ..config.effects import parse_effect_args
    from ..drivers.protocols.bench_config import check_tick
    from ..sim_backend.bench_day import refuse_effects_not_acting
    from ..sim_backend.rig import SimulatedRig

    check_tick(args.block, args.fs, f"--block {args.block} (--fs {args.fs:g})")  # as a bench file's [sim] block_samples
    effects = parse_effect_args(args.effect)
    refuse_effects_not_acting(args.rig or DEFAULT_RIG, effects)
    rig = SimulatedRig(args.rig or DEFAULT_RIG, fs_hz=args.fs, seed=args.seed, effects=effects,
                       frequency_hz=args.freq, current_pp_a=args.ipp)
    return RigSource(rig, block_samples=args.block, pace=args.pace, duration_s=args.seconds)


def _print_estimate(topic: str, obj: dict) -> None:
    if topic == "/estimate":
        print(format_message("estimate", json.dumps(obj).encode()), flush=True)


def _quiet_on_broken_pipe(show: Callable[[str, dict], None]) -> Callable[[str, dict], None]:
    """``record -v | head``, ``replay | head``: once the reader has gone, stop printing and go on."""
    gone = False

    def listener(topic: str, obj: dict) -> None:
        nonlocal gone
        if not gone:
            try:
                show(topic, obj)
            except BrokenPipeError:
                gone = True

    return listener


def cmd_record(args: argparse.Namespace) -> int:
    """`hystbench record`: a source through the pipeline into one MCAP log, no daemon; a failed log
    that holds no measurement is removed, so it does not block the retry."""
    from ..acquisition.record import has_measurement, record_log

    out = Path(args.out)
    ours = args.overwrite or not out.exists()  # else the recorder refuses it and it must stay as it is
    src = _source_from_args(args)
    try:
        with noting(signal.SIGINT) as interrupted:  # record_log ends the log cleanly on Ctrl-C and returns
            res = record_log(src, out, compression=args.compression, overwrite=args.overwrite,
                             on_message=_quiet_on_broken_pipe(_print_estimate) if args.verbose else None)
    except BenchError as err:  # a log with no measurement in it would only block the retry: remove it
        if ours and out.is_file() and not has_measurement(out):
            out.unlink()
            raise RecordingError(f"{err} (nothing was recorded with the output on; {out} removed)") from err
        raise
    except KeyboardInterrupt:  # outside the pipeline's run (opening or closing the log)
        if ours and out.is_file():
            print(f"hystbench record: interrupted; {out} may be cut short (`hystbench recover {out}` salvages "
                  "its complete chunks)", file=sys.stderr)
        else:
            print("hystbench record: interrupted before anything was recorded", file=sys.stderr)
        return 130
    finally:
        src.close()
    errs = sum(1 for e in res["estimates"] if e.get("error"))
    print(f"wrote {', '.join(res['log'])}: {res['samples']} samples x {len(src.channels)} channels, "
          f"{len(res['estimates'])} estimates ({errs} refused), {res['bytes'] / 1e6:.2f} MB")
    if interrupted:
        print(f"hystbench record: interrupted; the log is closed and valid, with the {res['samples']} samples "
              f"recorded before it: {', '.join(res['log'])}", file=sys.stderr)
        return 130
    return 0


#: how long ``replay --foxglove`` waits for a Foxglove client to subscribe before it gives up
REPLAY_WAIT_S = 600.0


def cmd_replay(args: argparse.Namespace) -> int:
    """`hystbench replay`: a log through the same pipeline again, with the settings it was recorded
    with, so a replay gives what the live run gave."""
    from ..acquisition.record import replay_log

    if args.foxglove is not None:
        return _replay_to_foxglove(args)
    ests = replay_log(args.log, speed=args.speed or "max", out=args.out, overwrite=args.overwrite,
                      on_message=None if args.json else _quiet_on_broken_pipe(_print_estimate))
    return _replayed(args, ests)


def _replayed(args: argparse.Namespace, ests: list[dict]) -> int:
    """A replay's summary (or its estimates as JSON, NaN as null), and its exit: 1 when every window
    was refused (nothing measured; the live run may have refused them too), else 0."""
    from ..messages import json_text

    refused = sum(1 for e in ests if e.get("error"))
    print(json_text(ests) if args.json else f"{len(ests)} estimates ({refused} refused) from {args.log}", flush=True)
    if ests and refused == len(ests):
        print(f"hystbench replay: every one of the {len(ests)} windows of {args.log} was refused (the first: "
              f"{ests[0]['error']})", file=sys.stderr)
        return 1
    return 0


def _replay_to_foxglove(args: argparse.Namespace) -> int:
    """`hystbench replay LOG --foxglove [HOST:]PORT`: the replay served on the daemon's live view
    (:class:`~hystbench.service.foxglove_live.FoxgloveLive`: ``/plot/<channel>``, ``/plot/samples``,
    ``/estimate``, ... on the log's clock), so a layout made live shows the replay.  It starts once a
    client has subscribed (at most :data:`REPLAY_WAIT_S`), at the log's own pace unless ``--speed max``;
    at its end ``/status`` says ``replay_finished`` and the view is served until its clients have left
    (at most :data:`REPLAY_WAIT_S`), so that they get everything and can look at it."""
    from ..acquisition.record import replay_log
    from ..errors import ConfigError
    from ..service.foxglove_live import FoxgloveLive

    if args.out is not None:
        raise ConfigError("--out: not with --foxglove (record the replay without a view, or view it unrecorded)")
    host, port = args.foxglove
    view = None

    def serve(pipe) -> None:  # the view on the replay's pipeline, before it starts: a client first
        nonlocal view
        src = pipe.source
        view = FoxgloveLive(host, port, name=f"replay {Path(args.log).name}", channels=list(src.channels),
                            fs_hz=src.fs_hz, where="--foxglove").start()
        view.attach(pipe)
        print(f"hystbench replay: Foxglove view on {view.url}; the replay starts when a client subscribes "
              f"(at most {REPLAY_WAIT_S:g} s; Ctrl-C stops)", flush=True)
        if not view.wait_for_client(REPLAY_WAIT_S):
            raise ConfigError(f"--foxglove: no Foxglove client subscribed on {view.url} within {REPLAY_WAIT_S:g} s; "
                              "nothing replayed")

    try:
        ests = replay_log(args.log, speed="max" if args.speed == "max" else "realtime",
                          on_message=None if args.json else _print_estimate, prepare=serve)
        # said on /status (after every estimate: one queue, one thread), then served until the clients leave
        view.on_message("/status", {"t_ns": ests[-1]["t_ns"] if ests else 0, "level": "info",
                                    "event": "replay_finished", "message": f"{len(ests)} estimates from {args.log}",
                                    "estimates": len(ests)})
        view.drain(REPLAY_WAIT_S)
        print(f"hystbench replay: finished ({len(ests)} estimates); serving until every Foxglove client has left "
              f"(at most {REPLAY_WAIT_S:g} s; Ctrl-C stops)", file=sys.stderr, flush=True)
        view.wait_for_clients_to_leave(REPLAY_WAIT_S)
    finally:
        if view is not None:
            view.close()
    return _replayed(args, ests)


def cmd_export(args: argparse.Namespace) -> int:
    """`hystbench export`: an MCAP log's segments as interchange-format recordings (CSV + JSON), for
    the offline commands and other programs."""
    from ..analysis.log_recordings import read_mcap_segments
    from ..formats.recording import recording_paths, sweep_stem, write_sweep

    recs = read_mcap_segments(args.log, include_idle=args.include_idle)
    stems: list[str] = []
    for k, rec in enumerate(recs):
        off, settling = rec.metadata.get("output_on") is False, bool(rec.metadata.get("settling"))
        stem = sweep_stem(rec) + ("_off" if off else "_settling" if settling else "")
        if stem in stems:
            stem = f"{stem}_seg{k}"
        stems.append(stem)
    # every recording written before a line is printed: a closed stdout loses none of them
    for rec, stem in zip(recs, write_sweep(recs, args.out, overwrite=args.overwrite, names=stems)):
        state = "output off" if rec.metadata.get("output_on") is False else f"{rec.current_pp_a:g} A-pp"
        state += ", settling" if rec.metadata.get("settling") else ""
        print(f"wrote {recording_paths(stem)[1]} ({rec.n} samples at {rec.fs_hz:g} Hz, {rec.frequency_hz:g} Hz, "
              f"{state})")
    return 0


def cmd_recover(args: argparse.Namespace) -> int:
    """`hystbench recover`: the complete chunks of a log whose writer was killed, or whose bytes were
    damaged, salvaged into a new log, with what was lost: which byte ranges were skipped and why,
    how many chunks and messages."""
    from ..formats.mcaplog import recover

    rep = recover(args.log, args.out, overwrite=args.overwrite)
    if args.json:
        print(json.dumps(rep.as_dict(), indent=2))
        return 0
    d = rep.as_dict()
    why = "the log was complete" if rep.complete and not rep.skipped else \
        f"{len(rep.skipped)} damaged or cut region(s)" + (f"; stopped: {rep.stopped}" if rep.stopped else "")
    print(f"wrote {rep.out}: {rep.messages} messages from {rep.chunks} chunks "
          f"({', '.join(f'{k} {v}' for k, v in sorted(d['by_topic'].items()))}); "
          f"{d['bytes_lost']} of {d['bytes_total']} bytes not salvaged ({why})")
    for s in rep.skipped:
        print(f"  skipped bytes {s.start}-{s.end} ({s.bytes} bytes): {s.why}")
    if rep.skipped or rep.chunks_lost or rep.messages_lost:
        messages = "" if rep.messages_lost is None else f", {rep.messages_lost} messages"
        print(f"  lost: {rep.chunks_lost} chunk(s){messages} ({rep.lost_counted_from})")
    return 0


def cmd_daemon(args: argparse.Namespace) -> int:
    """`hystbench daemon`: the bench service (systemd-ready; SIGHUP reloads its file)."""
    from ..service.daemon import run_daemon

    return run_daemon(args.config)


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add watch, record, replay, export, recover and daemon to the ``hystbench`` parser."""
    from .args import (SIM_MAX_IPP_A, float_in, int_in, nonnegative_float, nonnegative_int, path_arg,
                       positive_float, positive_int)
    from .router import foxglove_address

    p = subparsers.add_parser("watch", help="print live messages of a bench from zenoh (estimates by default)")
    p.add_argument("keyexpr", nargs="?", type=_keyexpr, default="hystbench/*/estimate",
                   help="zenoh key expression (default hystbench/*/estimate; e.g. hystbench/bench1/**)")
    p.add_argument("--connect", action="append", metavar="ENDPOINT",
                   help=f"endpoint of the daemon (default {DEFAULT_CONNECT}; repeatable)")
    p.add_argument("--zenoh-config", metavar="FILE", type=path_arg,
                   help="zenoh json5 config (e.g. with user/password or TLS)")
    p.add_argument("--count", type=positive_int, help="stop after N messages (exit 1 if fewer came in --seconds)")
    p.add_argument("--seconds", type=positive_float, help="stop after S seconds (exit 1 if nothing came)")
    p.add_argument("--json", action="store_true", help="one JSON object per line")
    p.add_argument("--quiet-after", type=nonnegative_float, default=5.0, metavar="S",
                   help="say on stderr when nothing arrived for S seconds (default 5; 0: never)")
    p.set_defaults(func=cmd_watch)
    _register_ctl(subparsers)

    p = subparsers.add_parser("record", help="record the configured source to an MCAP log (no daemon)")
    p.add_argument("--out", type=path_arg, required=True, help="the log, e.g. run.mcap")
    p.add_argument("--seconds", type=float_in(0.0, MAX_RECORD_S), default=2.0,
                   help=f"how long (default 2, at most {MAX_RECORD_S:g})")
    p.add_argument("--source", choices=("bench", "sim", "synthetic", "zenoh"), default="bench",
                   help="bench (default): the instruments of --bench-file through the drivers, emulated when the "
                        "file says backend = \"sim\" (the shipped one does); sim: the simulated rig directly; "
                        "synthetic: precomputed sines; zenoh: what the daemon of --bench publishes, wherever it "
                        "runs (through --connect, e.g. a router)")
    p.add_argument("--bench-file", type=path_arg,
                   help="bench file for --source bench (default: hystbench/config/bench.toml)")
    p.add_argument("--bench", default="bench1", help="--source zenoh: the daemon's bench name (default bench1)")
    p.add_argument("--connect", action="append", metavar="ENDPOINT",
                   help="--source zenoh: where to reach it (repeatable; default tcp/127.0.0.1:7447)")
    p.add_argument("--zenoh-config", metavar="FILE", type=path_arg, help="--source zenoh: a zenoh json5 file instead")
    p.add_argument("--rig", default=None, help=f"the rig (default {DEFAULT_RIG}; --source bench: the emulated rig, in place "
                                              "of the bench file's [sim] rig)")
    p.add_argument("--freq", type=positive_float, default=320.0, help="excitation frequency, Hz (default 320)")
    p.add_argument("--ipp", type=float_in(0.0, SIM_MAX_IPP_A), default=1.4,
                   help=f"peak-to-peak current, A (default 1.4, at most {SIM_MAX_IPP_A:g})")
    p.add_argument("--fs", type=positive_float, default=100_000.0, help="sample rate, Hz (default 100000)")
    p.add_argument("--block", type=int_in(1, MAX_BLOCK_SAMPLES), default=1000,
                   help=f"samples per source block (default 1000, at most {MAX_BLOCK_SAMPLES:g})")
    p.add_argument("--pace", choices=("realtime", "max"), default="realtime")
    p.add_argument("--seed", type=nonnegative_int, default=0)
    p.add_argument("--effect", action="append", default=[], metavar="NAME=VALUE")
    p.add_argument("--compression", choices=("zstd", "lz4", "none"), default="zstd")
    p.add_argument("--overwrite", action="store_true")
    p.add_argument("--verbose", "-v", action="store_true", help="print each estimate")
    p.set_defaults(func=cmd_record, record_defaults={k: p.get_default(k) for k in _RECORD_KEYS})

    p = subparsers.add_parser("replay", help="feed an MCAP log through the pipeline again")
    p.add_argument("log", type=path_arg)
    p.add_argument("--speed", choices=("realtime", "max"), default=None,
                   help="the log's own pace, or as fast as the pipeline goes (default max; realtime with --foxglove)")
    p.add_argument("--out", type=path_arg, help="record the replay (with its estimates) to this log")
    p.add_argument("--overwrite", action="store_true")
    p.add_argument("--json", action="store_true", help="print the estimates as JSON")
    p.add_argument("--foxglove", type=foxglove_address, metavar="[HOST:]PORT",
                   help="serve the replay on a Foxglove WebSocket view, the daemon's channels (/plot/<channel>, "
                        "/estimate, ...); starts when a client subscribes; HOST defaults to 127.0.0.1")
    p.set_defaults(func=cmd_replay)

    p = subparsers.add_parser("export", help="write an MCAP log's segments as interchange-format recordings")
    p.add_argument("log", type=path_arg)
    p.add_argument("--out", type=path_arg, required=True, help="output folder")
    p.add_argument("--include-idle", action="store_true",
                   help="also segments with the output off (STEM_off) and the settling after each change (STEM_settling)")
    p.add_argument("--overwrite", action="store_true")
    p.set_defaults(func=cmd_export)

    p = subparsers.add_parser("recover", help="salvage the complete chunks of a log whose writer was killed or "
                                               "whose bytes were damaged (says what was lost)")
    p.add_argument("log", type=path_arg)
    p.add_argument("--out", type=path_arg, help="the salvaged log (default LOG-recovered.mcap)")
    p.add_argument("--overwrite", action="store_true")
    p.add_argument("--json", action="store_true")
    p.set_defaults(func=cmd_recover)

    p = subparsers.add_parser("daemon", help="run the bench daemon (systemd-ready; SIGHUP reloads)")
    p.add_argument("--config", type=path_arg, help="daemon TOML (default: built-in defaults, the simulated rig)")
    p.set_defaults(func=cmd_daemon)
