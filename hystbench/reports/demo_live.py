"""The demo's live part: the bench service on the emulated bench, a sweep commanded over zenoh.

What ``make demo`` shows first: the daemon's pipeline in-process, a short sweep started the way an
operator starts one (``hystbench ctl``'s control path), live estimates as they arrive, an MCAP
log.  A failure (the instruments do not answer, the machine is too slow for the emulated bench)
is reported, its files removed, and the demo goes on with its offline parts.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Callable

from rich.markup import escape

from ..acquisition.zenoh_bus import Subscription, free_port, key
from ..deadline import Deadline
from ..errors import BenchError
from ..service.control import BenchControl
from ..service.daemon_config import load_daemon_config
from ..service.service import BenchService

__all__ = ["demo_live"]

#: ``show(key, payload)``: one live message as it arrives (the command line prints it).
Show = Callable[[str, bytes], None]


def _clear_demo_live(out: Path, *, remove_dir: bool = False) -> None:
    """Remove what :func:`demo_live` writes in ``out`` (its config and ``demo-*.mcap`` logs), so
    the folder only ever holds the last run's log; ``remove_dir``: the folder too, if then empty."""
    if not out.is_dir():
        return
    for p in [out / "demo-daemon.toml", *out.glob("demo-*.mcap")]:
        p.unlink(missing_ok=True)
    if remove_dir and not any(out.iterdir()):
        out.rmdir()


#: While the sweep runs, each message gives it at least this long again (seconds).
_STILL_COMING_S = 10.0


def _follow_sweep(ests: Subscription, status: Subscription, wait_s: float, got: list[dict], errors: list[str],
                  show: Show | None) -> list[float]:
    """Take estimates as they arrive (``show`` each) until the sweep says it is done (or
    ``wait_s`` passes), then those still on their way (a source behind the wall clock delivers the
    last points late); the frequencies the sweep announced.  The sweep dwells on the source's sample
    clock, so a source slower than real time takes longer: the wait goes on while messages still come."""
    points: list[float] = []
    done = False
    deadline = Deadline(wait_s)
    while not deadline.expired:
        item = ests.get(deadline.left(1.0 if done else 0.1))
        if item is not None:
            got.append(json.loads(item[1]))
            if show is not None:
                show(item[0], item[1])
            deadline = deadline if done else _at_least(deadline, _STILL_COMING_S)
        elif done:  # a second without an estimate after the sweep: the pipeline has caught up
            break
        while (st := status.get(0.0)) is not None:
            deadline = deadline if done else _at_least(deadline, _STILL_COMING_S)
            obj = json.loads(st[1])
            if obj.get("level") == "error":
                errors.append(str(obj.get("message") or obj.get("event")))
            if obj.get("event") == "sweep_point":
                points.append(float(obj.get("frequency_hz", "nan")))
            done = done or obj.get("event") in ("sweep_done", "sweep_stopped")
    return points


def _at_least(deadline: Deadline, seconds: float) -> Deadline:
    """``deadline``, or a new one ``seconds`` from now if that is later."""
    return deadline if deadline.left() >= seconds else Deadline(seconds)


def demo_live(out_dir: str | Path, seconds: float = 6.0, source: str = "bench", *,
              show: Show | None = None, bench_file: str | Path | None = None) -> dict[str, Any]:
    """The daemon's pipeline in-process, driven the way an operator drives a bench: a short sweep
    started with ``hystbench ctl``'s control path over zenoh (an ephemeral port on 127.0.0.1)
    through the emulated instruments' drivers (``source="bench"``; ``"sim"``: the simulated rig
    directly), each live estimate given to ``show(key, payload)`` as it arrives (the command line
    prints it), an MCAP log in ``out_dir``.

    The result's ``summary`` is one line for the demo to print.  If the live part fails (the
    instruments do not answer, the machine is too slow for the emulated bench, no estimate came),
    ``error`` says why and this run leaves nothing in ``out_dir``: the demo says so and goes on."""
    out = Path(out_dir)
    _clear_demo_live(out)  # an earlier run's log is not this run's
    port = free_port()
    freqs = [80.0, 160.0, 320.0]
    dwell = max(seconds / len(freqs), 0.5)
    toml = out / "demo-daemon.toml"
    out.mkdir(parents=True, exist_ok=True)
    bench_key = f'bench_file = "{Path(bench_file).as_posix()}"\n' if bench_file else ""  # e.g. the digitiser's
    toml.write_text(f'[daemon]\nbench = "demo"\nlog_dir = "{out.as_posix()}"\n[source]\nkind = "{source}"\n{bench_key}'
                    f'[zenoh]\nlisten = ["tcp/127.0.0.1:{port}"]\n[sweep]\nfrequencies_hz = {freqs}\n'
                    f'dwell_s = {dwell:g}\n', encoding="utf-8")
    svc, paths, got, errors, points, error = None, [], [], [], [], None
    try:
        svc = BenchService(load_daemon_config(toml)).start()
        with BenchControl("demo", connect=[f"tcp/127.0.0.1:{port}"], timeout_s=10.0) as ctl:
            ests = Subscription(ctl.session, key("demo", "estimate"))
            status = Subscription(ctl.session, key("demo", "status"))
            try:
                ctl.request("start_sweep", {"frequencies_hz": freqs, "dwell_s": dwell})
                points = _follow_sweep(ests, status, len(freqs) * dwell + 10.0, got, errors, show)
                health = ctl.health()
            finally:
                ests.close()
                status.close()
        if health.get("pipeline_error"):
            error = f"the pipeline failed: {health['pipeline_error']}"
    except BenchError as err:
        error = str(err)
    finally:
        if svc is not None:
            try:
                paths = svc.stop()
            except BenchError as err:
                error = error or f"stopping the bench: {err}"
    good = [e for e in got if not e.get("error")]
    if error is None and not good:
        error = (f"no live estimate during the {len(freqs) * dwell:g} s sweep"
                 + (f" ({errors[-1]})" if errors else "") + "; the machine may be too slow for the emulated "
                 "bench at 100 kS/s")
    if error is not None:
        _clear_demo_live(out, remove_dir=True)
        return {"error": error, "log": [], "estimates": len(got), "refused": len(got) - len(good), "points": points,
                "hysteresis_deg": {}, "summary": f"[bold red]live part failed[/]: {escape(error)}\n"
                                                 "(its partial log removed; the demo goes on without it)"}
    by_f: dict[float, list] = {}
    for e in good:
        if e["phases_deg"].get("hysteresis") is not None:
            by_f.setdefault(e["nominal_frequency_hz"], []).append(e["phases_deg"]["hysteresis"])
    logs = [str(p) for p in paths]
    return {"log": logs, "estimates": len(got), "refused": len(got) - len(good), "error": None, "points": points,
            "hysteresis_deg": {f"{f:g}": sum(v) / len(v) for f, v in sorted(by_f.items()) if v},
            "summary": f"{len(got)} live estimates ({len(got) - len(good)} refused while settling); "
                       f"MCAP log: {escape(', '.join(logs))}"}
