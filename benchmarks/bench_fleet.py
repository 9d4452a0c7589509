"""A fleet through one zenoh router: does every estimate of every bench reach a subscriber there?

Issue 31.  For each N of ``--benches``: a router (``hystbench.service.router.Router``, in this
process) on a free loopback port, a subscriber on the router's own session counting every
``hystbench/*/estimate`` per bench from before any daemon starts, and N ``hystbench daemon``
processes (the simulated rig, ``[zenoh] listen = []``, ``connect = [the router]``, a sweep
started at once, raw blocks published as by default, no log) on this machine.  Start-up: from
spawning the daemons to every bench answering ``health`` through the router, sweeping.  Then a
window of ``--seconds``; at its end each bench's health is asked through the router, and the
estimates it says it published (``estimates``) are compared with those the subscriber had
received when that reply came (the reply and the estimates travel the same link in order, so
every estimate counted before the reply was put before it).  Also measured over the window: each
bench's estimates per second (the estimation stage skips windows it has no CPU for: fewer
estimates, none lost), the
CPU of the daemons (sum, in cores) and of this process (router and subscriber), the machine's
busy fraction (/proc/stat: other work on the machine counts too), and each bench's samples per
second against its sample rate (a bench that falls behind real time shows it here first), and
the daemons' resident memory at the end.
With ``--foxglove``: the router also serves its Foxglove view of the fleet
(:class:`~hystbench.service.foxglove_live.FoxgloveFleet`, as ``hystbench router --foxglove``) and a
WebSocket client (the ``websockets`` package speaking ``foxglove.sdk.v1``) subscribes to every
channel as it is advertised; over the window it counts the messages per second it received on each
``/<bench>/<topic>`` channel (each bench's ``/estimate`` against what the bench published in the
window), and the view's own counters (sent, dropped) at the end.
Run: ``python -m benchmarks fleet [--benches 1 2 4 8] [--seconds 10] [--foxglove] [--json]``.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

HANG_S = 120.0  #: a bench that has not answered by then is a failure (start-up on a loaded machine)
MAX_BENCHES = 16  #: the largest fleet this runs (each daemon is a process with the simulated rig)
MAX_SECONDS = 120.0
FS_HZ = 100_000.0  #: the simulated rig's sample rate (the daemon's default)
_TICK = os.sysconf("SC_CLK_TCK")


def cpu_s(pid: int | str) -> float:
    """User + system CPU seconds of a process so far (/proc/<pid>/stat), 0 once it has gone."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return 0.0
    return (int(fields[11]) + int(fields[12])) / _TICK


def rss_mb(pid: int) -> float:
    """Resident memory of a process, MB (/proc/<pid>/status ``VmRSS``), 0 once it has gone."""
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) * 1024 / 1e6
    except OSError:
        pass
    return 0.0


def machine_busy() -> tuple[float, float]:
    """(busy, total) jiffies of the whole machine (/proc/stat), for a busy fraction over a window."""
    values = [int(v) for v in Path("/proc/stat").read_text().splitlines()[0].split()[1:]]
    idle = values[3] + values[4]
    return sum(values) - idle, sum(values)


def daemon_file(folder: Path, bench: str, router: str, seconds: float) -> Path:
    path = folder / f"{bench}.toml"
    path.write_text(f'[daemon]\nbench = "{bench}"\nlog_dir = "{(folder / "logs").as_posix()}"\n'
                    '[source]\nkind = "sim"\n[recording]\nenabled = false\n'
                    f'[zenoh]\nlisten = []\nconnect = ["{router}"]\n'
                    f'[sweep]\nfrequencies_hz = [80.0, 160.0, 320.0, 480.0]\ndwell_s = {max(seconds, 1.0):g}\n'
                    'autostart = true\n', encoding="utf-8")
    return path


class FoxgloveCounter(threading.Thread):
    """A Foxglove WebSocket client on its own thread: subscribes to each channel as it is advertised
    and counts the message data it receives per topic (:meth:`counts`)."""

    def __init__(self, url: str) -> None:
        super().__init__(name="foxglove-counter", daemon=True)
        from websockets.sync.client import connect

        self.ws = connect(url, subprotocols=["foxglove.sdk.v1"], open_timeout=HANG_S, max_size=None)
        self.stop = threading.Event()
        self._lock = threading.Lock()
        self._count: dict[str, int] = {}
        self._topic_of: dict[int, str] = {}
        self._channel_of: dict[int, int] = {}
        self.resubscribed = 0

    def run(self) -> None:
        import struct

        while not self.stop.is_set():
            try:
                msg = self.ws.recv(timeout=0.2)
            except TimeoutError:
                continue
            except Exception:  # closed
                return
            if isinstance(msg, bytes) and msg[0] == 0x01:
                topic = self._topic_of.get(struct.unpack_from("<I", msg, 1)[0], "?")
                with self._lock:
                    self._count[topic] = self._count.get(topic, 0) + 1
            elif isinstance(msg, str):
                j = json.loads(msg)
                if j.get("op") == "advertise":
                    subs = []
                    for c in j["channels"]:
                        k = len(self._topic_of) + 1
                        self._topic_of[k] = c["topic"]
                        self._channel_of[k] = c["id"]
                        subs.append({"id": k, "channelId": c["id"]})
                    self.ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))
                elif j.get("op") == "status" and str(j.get("message")).startswith("Unknown channel ID: "):
                    # foxglove-sdk 0.30.3 may refuse a subscribe sent at once after a channel's advertise
                    # (docs/fleet.md): again, counted
                    self.resubscribed += 1
                    cid = int(j["message"].rsplit(" ", 1)[1])
                    self.ws.send(json.dumps({"op": "subscribe", "subscriptions": [
                        {"id": k, "channelId": c} for k, c in self._channel_of.items() if c == cid]}))

    def counts(self) -> dict[str, int]:
        with self._lock:
            return dict(self._count)

    def close(self) -> None:
        self.stop.set()
        self.join(HANG_S)
        self.ws.close()


def run(n: int, seconds: float, foxglove: bool = False, record: bool = False) -> dict:
    """One fleet of ``n`` benches for a window of ``seconds``: the figures of one row.  ``record``:
    the first bench is also recorded through the router for the window (``record --source zenoh``'s
    ``ZenohSource`` in this process, whose CPU then counts as the router's)."""
    from hystbench.acquisition.zenoh_bus import _json_object, free_port
    from hystbench.deadline import Deadline
    from hystbench.service.router import Router

    endpoint = f"tcp/127.0.0.1:{free_port()}"
    benches = [f"fleet{i + 1}" for i in range(n)]
    received = {b: 0 for b in benches}
    lock = threading.Lock()

    def on_estimate(sample) -> None:
        bench = str(sample.key_expr).split("/")[1]
        with lock:
            received[bench] = received.get(bench, 0) + 1

    def health(session, bench: str, timeout_s: float) -> tuple[dict | None, int]:
        """The bench's health through the router, and the estimates received when it came."""
        for reply in session.get(f"hystbench/{bench}/health", timeout=timeout_s):
            with lock:
                got = received.get(bench, 0)
            if reply.ok is not None:
                return _json_object(reply.ok.payload.to_bytes()), got
        return None, 0

    with tempfile.TemporaryDirectory(prefix="hystbench-bench-fleet-") as tmp, Router([endpoint]) as router:
        folder = Path(tmp)
        session = router.session
        sub = session.declare_subscriber("hystbench/*/estimate", on_estimate)
        view = counter = None
        if foxglove:
            from hystbench.service.foxglove_live import FoxgloveFleet

            view = FoxgloveFleet("127.0.0.1", free_port()).start(session)
            counter = FoxgloveCounter(view.url)
            counter.start()
        env = dict(os.environ, STATE_DIRECTORY=str(folder / "state"), PYTHONUNBUFFERED="1")
        env.pop("NOTIFY_SOCKET", None)
        root = Path(__import__("hystbench").__file__).resolve().parents[1]
        t_spawn = time.monotonic()
        procs = {b: subprocess.Popen([sys.executable, "-m", "hystbench", "daemon", "--config",
                                      str(daemon_file(folder, b, endpoint, seconds))], cwd=root, env=env,
                                     stdout=subprocess.DEVNULL, stderr=open(folder / f"{b}.stderr", "wb"))
                 for b in benches}
        try:
            ready: dict[str, float] = {}
            deadline = Deadline(HANG_S)
            while len(ready) < n:  # every bench answering through the router, sweeping
                for b in benches:
                    if b in ready:
                        continue
                    if procs[b].poll() is not None or deadline.expired:
                        raise RuntimeError(f"bench {b} not ready after {deadline.elapsed:.0f} s (exit "
                                           f"{procs[b].poll()}): {(folder / f'{b}.stderr').read_text()[-1500:]}")
                    h, _ = health(session, b, deadline.left(0.5))
                    if h is not None and h.get("state") == "sweeping" and h.get("samples"):
                        ready[b] = time.monotonic() - t_spawn
            start = {b: health(session, b, HANG_S) for b in benches}
            cpu0 = {b: cpu_s(p.pid) for b, p in procs.items()}
            own0, busy0, t0 = cpu_s("self"), machine_busy(), time.monotonic()
            fox0 = counter.counts() if counter else {}
            recorded = _start_recording(benches[0], endpoint, seconds, folder) if record else None
            threading.Event().wait(seconds)  # the window: the fleet runs, the subscriber counts
            fox1 = counter.counts() if counter else {}
            ends = {b: health(session, b, HANG_S) for b in benches}
            t1 = time.monotonic()
            cpu1 = {b: cpu_s(p.pid) for b, p in procs.items()}
            own1, busy1 = cpu_s("self"), machine_busy()
            rss = sum(rss_mb(p.pid) for p in procs.values())
            remote = _finish_recording(*recorded) if recorded else None
        finally:
            for p in procs.values():
                if p.poll() is None:
                    p.terminate()
            for p in procs.values():
                try:
                    p.wait(HANG_S)
                except subprocess.TimeoutExpired:
                    p.kill()
                    p.wait()
            sub.undeclare()
            if counter is not None:
                counter.close()
            view_health = view.health() if view is not None else None
            if view is not None:
                view.close()
    window = t1 - t0
    rows = {}
    for b in benches:
        h, got = ends[b]
        published = int(h["estimates"]) if h else 0
        h0, got0 = start[b]
        rate = (h["samples"] - h0["samples"]) / window if h and h0 else 0.0
        in_window = published - int(h0["estimates"]) if h0 else 0
        rows[b] = {"published": published, "received": got, "lost": max(0, published - got),
                   "estimates_per_s": round(in_window / window, 2), "received_per_s": round((got - got0) / window, 2),
                   "samples_per_s": round(rate), "ready_s": round(ready[b], 2)}
    return {
        "benches": n, "seconds": round(window, 2),
        "startup_s": round(max(ready.values()), 2),
        "published": sum(r["published"] for r in rows.values()),
        "received": sum(r["received"] for r in rows.values()),
        "lost": sum(r["lost"] for r in rows.values()),
        "estimates_per_s_per_bench": [min(r["estimates_per_s"] for r in rows.values()),
                                      max(r["estimates_per_s"] for r in rows.values())],
        "slowest_samples_per_s": min(r["samples_per_s"] for r in rows.values()),
        "realtime_fraction_min": round(min(r["samples_per_s"] for r in rows.values()) / FS_HZ, 3),
        "daemons_cpu_cores": round(sum(cpu1[b] - cpu0[b] for b in benches) / window, 2),
        "router_cpu_cores": round((own1 - own0) / window, 3),
        "daemons_rss_mb": round(rss),
        "machine_busy": round((busy1[0] - busy0[0]) / max(1, busy1[1] - busy0[1]), 2),
        "cores": os.cpu_count(), "per_bench": rows,
        **({"foxglove": _foxglove_rates(fox0, fox1, window, benches, view_health, counter.resubscribed)}
           if foxglove else {}),
        **({"remote_record": remote} if record else {}),
    }


def _start_recording(bench: str, endpoint: str, seconds: float, folder: Path):
    """``record --source zenoh`` of ``bench`` through the router, for ``seconds`` of its samples, in a thread."""
    from hystbench.acquisition.record import record_log
    from hystbench.acquisition.zenoh_source import ZenohSource
    from hystbench.service.control import client_config

    src = ZenohSource(bench, client_config([endpoint]), duration_s=seconds, timeout_s=HANG_S)
    out = folder / f"{bench}-remote.mcap"
    done: dict = {}

    def work() -> None:
        t0 = time.monotonic()
        try:
            done["summary"] = record_log(src, out)
        except Exception as err:  # reported in the row, not raised in the thread
            done["error"] = f"{type(err).__name__}: {err}"
        done["wall_s"] = time.monotonic() - t0

    thread = threading.Thread(target=work, name="remote-record")
    thread.start()
    return thread, src, out, done


def _finish_recording(thread: threading.Thread, src, out: Path, done: dict) -> dict:
    from hystbench.formats.mcaplog.reader import iter_blocks

    thread.join(HANG_S)
    src.close()
    if "summary" not in done:
        return {"error": done.get("error", "did not finish")}
    blocks = list(iter_blocks(out))
    samples = sum(b.n for b in blocks)
    lost = sum(b.gap_samples for b in blocks)
    return {"samples": samples, "lost_samples": lost, "gaps": sum(1 for b in blocks if b.gap_samples),
            "estimates": len(done["summary"]["estimates"]), "megabytes": round(out.stat().st_size / 1e6, 2),
            "samples_per_wall_s": round((samples + lost) / done["wall_s"])}


def _foxglove_rates(before: dict[str, int], after: dict[str, int], window: float, benches: list[str],
                    view: dict | None, resubscribed: int) -> dict:
    """What the Foxglove client received per channel per second over the window, and the view's counters."""
    per_s = {t: round((c - before.get(t, 0)) / window, 2) for t, c in sorted(after.items())}
    estimates = [per_s.get(f"/{b}/estimate", 0.0) for b in benches]
    return {"per_channel_per_s": per_s, "estimates_received_per_s_per_bench": [min(estimates), max(estimates)],
            "view": view, "client_resubscribed": resubscribed}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks fleet", description=__doc__.split("\n")[0])
    parser.add_argument("--benches", type=int, nargs="+", default=[1, 2, 4, 8], metavar="N",
                        help=f"fleet sizes to run, one after the other (default 1 2 4 8; at most {MAX_BENCHES})")
    parser.add_argument("--seconds", type=float, default=10.0, help=f"the window per fleet (default 10, at most "
                                                                     f"{MAX_SECONDS:g})")
    parser.add_argument("--foxglove", action="store_true", help="also serve the router's Foxglove view of the fleet "
                                                                 "and count what a client receives per channel")
    parser.add_argument("--record", action="store_true", help="also record the first bench through the router "
                                                                 "for the window (record --source zenoh)")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args(argv)
    if not all(1 <= n <= MAX_BENCHES for n in args.benches) or not 0 < args.seconds <= MAX_SECONDS:
        parser.error(f"--benches in 1..{MAX_BENCHES}, --seconds in (0, {MAX_SECONDS:g}]")
    results = []
    for n in args.benches:
        r = run(n, args.seconds, args.foxglove, args.record)
        results.append(r)
        if not args.json:
            print(f"N={n:2d}: start-up {r['startup_s']:5.1f} s; estimates published {r['published']:5d}, received "
                  f"{r['received']:5d}, lost {r['lost']}; {r['estimates_per_s_per_bench'][0]:.1f}-"
                  f"{r['estimates_per_s_per_bench'][1]:.1f} estimates/s per bench in the window; slowest bench {r['realtime_fraction_min']:.2f} x real time; "
                  f"CPU daemons {r['daemons_cpu_cores']:.2f} + router {r['router_cpu_cores']:.3f} cores, machine "
                  f"{r['machine_busy']:.0%} busy ({r['cores']} cores); daemons' RSS {r['daemons_rss_mb']} MB", flush=True)
            if "foxglove" in r:
                fx = r["foxglove"]
                lo, hi = fx["estimates_received_per_s_per_bench"]
                v = fx["view"]
                print(f"      Foxglove client: {lo:.1f}-{hi:.1f} /<bench>/estimate messages/s per bench; "
                      f"view sent {v['messages_sent']}, dropped {v['dropped']}, rejected {v['rejected']}, "
                      f"errors {v['errors']}; the client subscribed again {fx['client_resubscribed']} time(s) "
                      "after an 'Unknown channel ID'", flush=True)
                for t, rate in fx["per_channel_per_s"].items():
                    print(f"        {t:<24}{rate:8.2f}/s", flush=True)
            if "remote_record" in r:
                rr = r["remote_record"]
                print("      remote record of fleet1 through the router: " + (rr["error"] if "error" in rr else
                      f"{rr['samples']} samples kept, {rr['lost_samples']} lost in {rr['gaps']} gap(s), "
                      f"{rr['estimates']} estimates, {rr['megabytes']} MB, {rr['samples_per_wall_s']} samples per "
                      "wall second"), flush=True)
    if args.json:
        print(json.dumps(results, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
