"""What a Foxglove client receives from the daemon's live view, and what serving it costs the daemon.

Starts ``hystbench daemon`` (the simulated rig, 100 kS/s, sweeping 40..480 Hz from the start; the log
written as by default; zenoh on a loopback port) three times: with ``[foxglove] enabled = false``
(the baseline), with the view on and no client, and with the view on and a WebSocket client (the ``websockets`` package
speaking ``foxglove.sdk.v1``, not foxglove-sdk's) subscribed to every channel it advertises.  Over
``--seconds`` it counts the client's messages and bytes per channel, and reads the daemon's CPU time
(``/proc/<pid>/stat``: user + system, as a fraction of one core) over the same window; at the end the
daemon's own counters (health's ``foxglove``: messages sent, items dropped, errors).
Run: ``python -m benchmarks foxglove [--seconds 20] [--repeat 3] [--json]``.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import struct
import subprocess
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path

from benchmarks.processes import stop_process

HANG_S = 120.0
BENCH = "fgbench"
FREQUENCIES = (40.0, 80.0, 160.0, 320.0, 480.0)


def cpu_s(pid: int) -> float:
    """User + system CPU seconds of a process so far (/proc/<pid>/stat, fields 14 and 15)."""
    with open(f"/proc/{pid}/stat", encoding="ascii") as f:
        fields = f.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


class Daemon:
    def __init__(self, folder: Path, *, foxglove: bool, seconds: float) -> None:
        from hystbench.acquisition.zenoh_bus import free_port

        self.endpoint = f"tcp/127.0.0.1:{free_port()}"
        self.port = free_port()
        dwell = max(1.0, (seconds + 10.0) / len(FREQUENCIES))  # the whole window inside one sweep
        cfg = folder / "daemon.toml"
        cfg.write_text(f'[daemon]\nbench = "{BENCH}"\nlog_dir = "{(folder / "logs").as_posix()}"\n'
                       '[source]\nkind = "sim"\n'
                       f'[zenoh]\nlisten = ["{self.endpoint}"]\n'
                       f'[foxglove]\nenabled = {str(foxglove).lower()}\nport = {self.port}\n'
                       f'[sweep]\nfrequencies_hz = {list(FREQUENCIES)}\ndwell_s = {dwell}\nautostart = true\n',
                       encoding="utf-8")
        self.stderr_path = folder / "daemon.stderr"
        env = dict(os.environ, STATE_DIRECTORY=str(folder / "state"), PYTHONUNBUFFERED="1")
        env.pop("NOTIFY_SOCKET", None)
        root = Path(__import__("hystbench").__file__).resolve().parents[1]
        with open(self.stderr_path, "wb") as err:
            self.proc = subprocess.Popen([sys.executable, "-m", "hystbench", "daemon", "--config", str(cfg)],
                                         cwd=root, env=env, stdout=subprocess.DEVNULL, stderr=err)

    def health(self, cond=lambda h: True) -> dict:
        import zenoh

        from hystbench.acquisition.zenoh_bus import load_zenoh_config, peer_config, query_json
        from hystbench.deadline import Deadline

        deadline = Deadline(HANG_S)
        with zenoh.open(load_zenoh_config(peer_config(connect=[self.endpoint]))) as s:
            while not deadline.expired:
                got = query_json(s, f"hystbench/{BENCH}/health", timeout_s=deadline.left(1.0))
                if got and cond(got[0]):
                    return got[0]
                if self.proc.poll() is not None:
                    break
        raise RuntimeError(f"no health from the daemon (exit {self.proc.poll()}): "
                           f"{self.stderr_path.read_text(errors='replace')[-2000:]}")

    def stop(self) -> int | None:
        """SIGTERM, then SIGKILL if it has not exited within HANG_S; its exit status."""
        return stop_process(self.proc, HANG_S)


def listen(port: int, seconds: float) -> dict:
    """Subscribe to every advertised channel; messages and bytes per channel over ``seconds``."""
    from websockets.sync.client import connect

    from hystbench.deadline import Deadline

    with connect(f"ws://127.0.0.1:{port}", subprotocols=["foxglove.sdk.v1"], open_timeout=HANG_S,
                 max_size=None) as ws:
        channels: dict[str, dict] = {}
        deadline = Deadline(HANG_S)
        while not channels and not deadline.expired:
            msg = ws.recv(timeout=deadline.left(1.0))
            if isinstance(msg, str) and json.loads(msg)["op"] == "advertise":
                channels = {c["topic"]: c for c in json.loads(msg)["channels"]}
        topic_of = {k: t for k, t in enumerate(sorted(channels), start=1)}
        ws.send(json.dumps({"op": "subscribe", "subscriptions": [
            {"id": k, "channelId": channels[t]["id"]} for k, t in topic_of.items()]}))
        count, size = Counter(), Counter()
        window = Deadline(seconds)
        while not window.expired:
            try:
                msg = ws.recv(timeout=max(0.01, window.left()))
            except TimeoutError:
                break
            if isinstance(msg, bytes) and msg[0] == 0x01:
                t = topic_of[struct.unpack_from("<I", msg, 1)[0]]
                count[t] += 1
                size[t] += len(msg)
        elapsed = window.elapsed
    return {"seconds": round(elapsed, 2),
            "channels": {t: {"messages_per_s": round(count[t] / elapsed, 1), "kB_per_s": round(size[t] / elapsed / 1e3, 1)}
                         for t in sorted(channels)},
            "total_messages_per_s": round(sum(count.values()) / elapsed, 1)}


def run(foxglove: bool, client: bool, seconds: float, settle: float) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        d = Daemon(Path(tmp), foxglove=foxglove, seconds=seconds + settle)
        try:
            d.health(lambda h: h["samples"] > 0 and h["state"] == "sweeping")
            time.sleep(settle)  # past start-up (imports, compilation): the steady state is measured
            s0 = d.health()["samples"]
            c0, t0 = cpu_s(d.proc.pid), time.monotonic()
            if foxglove and client:
                out = listen(d.port, seconds)
            else:
                time.sleep(seconds)
                out = {"seconds": seconds}
            c1, t1 = cpu_s(d.proc.pid), time.monotonic()
            h = d.health()
            s1 = h["samples"]
        finally:
            status = d.stop()
    out.update(foxglove=foxglove, client=client, daemon_cpu_fraction_of_a_core=round((c1 - c0) / (t1 - t0), 3),
               daemon_health_foxglove=h.get("foxglove"), estimates=h.get("estimates"), exit=status,
               source_samples_per_s=round((s1 - s0) / (t1 - t0)), load_average_1min=os.getloadavg()[0])
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m benchmarks foxglove", description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=20.0, help="measurement window (default 20)")
    ap.add_argument("--settle", type=float, default=3.0, help="seconds after start-up before measuring")
    ap.add_argument("--repeat", type=int, default=1, help="runs of each configuration, interleaved (CPU: median)")
    ap.add_argument("--json", action="store_true", help="one JSON document")
    a = ap.parse_args(argv)
    configs = ((False, False), (True, False), (True, True))
    runs = [run(fox, client, a.seconds, a.settle) for _ in range(a.repeat) for fox, client in configs]
    if a.json:
        print(json.dumps({"runs": runs, "cpus": os.cpu_count()}, indent=1))
        return 0
    names = ("view off", "view on, no client", "view on, a client on every channel")
    print(f"daemon on the simulated rig, sweeping; {a.repeat} x {a.seconds:g} s per configuration; {os.cpu_count()} cores")
    for (fox, client), name in zip(configs, names):
        rs = [r for r in runs if (r["foxglove"], r["client"]) == (fox, client)]
        cpu = sorted(r["daemon_cpu_fraction_of_a_core"] for r in rs)
        load = ", ".join(f"{r['load_average_1min']:.1f}" for r in rs)
        print(f"  {name:<36} CPU {statistics.median(cpu):.3f} of a core (runs {', '.join(f'{c:.3f}' for c in cpu)}); "
              f"source {statistics.median(r['source_samples_per_s'] for r in rs):.0f} samples/s; "
              f"load average {load}")
    on = [r for r in runs if r["client"]][-1]
    print(f"what the client received (last run, {on['seconds']:g} s):")
    print(f"  {'channel':<18}{'messages/s':>12}{'kB/s':>10}")
    for t, v in on["channels"].items():
        print(f"  {t:<18}{v['messages_per_s']:>12.1f}{v['kB_per_s']:>10.1f}")
    print(f"  {'total':<18}{on['total_messages_per_s']:>12.1f}")
    print(f"daemon's counters: {json.dumps(on['daemon_health_foxglove'])}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
