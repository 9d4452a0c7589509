"""The daemon's memory under a flood of command payloads: RSS before and after, from /proc.

Issue 26: 20 client sessions x 50 commands with a 10 kB payload added 259 MB to the daemon for
good; 100-byte payloads did not.  The 10 kB ones went through zenoh's shared memory (a payload of
3 KiB or more, between two processes of one host that both have it on, as zenoh has by default):
each client session made its own 16 MiB segment and the daemon kept every segment it had read
from mapped until it exited.  The daemon's sessions now take no shared memory (docs/zenoh.md).

This starts ``hystbench daemon`` (the simulated rig; no log, no estimation: nothing else grows)
on a loopback port, warms it up with one session of the same commands, reads its RSS
(``VmRSS``, with ``RssShmem``, the part that is shared memory), then runs ``--rounds`` floods of
``--sessions`` sessions one after the other, each sending ``--commands`` commands
(``cmd/output`` with a ``--size``-byte JSON payload that the daemon refuses for its unknown
argument) and waiting for each reply, and reads the RSS after each round.  The clients are plain
zenoh sessions with zenoh's defaults (shared memory on), as any client's would be.
Run: ``python -m benchmarks command_flood [--sessions 20] [--commands 50] [--size 10000] [--rounds 3]
[--json]``.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import tempfile
from pathlib import Path

from benchmarks.processes import stop_process

HANG_S = 120.0  #: a daemon that has not answered by then is a failure (start-up, a reply)
BENCH = "flood"
WARMUP_SESSIONS = 5  #: sessions of the same commands before the baseline (threads, buffers made once)


def memory(pid: int) -> dict[str, int]:
    """``VmRSS`` and ``RssShmem`` of a process, bytes (/proc/<pid>/status)."""
    out = {}
    with open(f"/proc/{pid}/status", encoding="ascii") as f:
        for line in f:
            name, _, value = line.partition(":")
            if name in ("VmRSS", "RssShmem", "Threads"):
                out[name] = int(value.split()[0]) * (1 if name == "Threads" else 1024)
    return out


def client_config(endpoint: str):
    """A client as anyone would write one: zenoh's defaults (shared memory on), connected to
    ``endpoint`` only (no scouting), listening nowhere."""
    import zenoh

    return zenoh.Config.from_json5(json.dumps({
        "mode": "peer", "connect": {"endpoints": [endpoint]}, "listen": {"endpoints": []},
        "scouting": {"multicast": {"enabled": False}, "gossip": {"enabled": False}}}))


class Daemon:
    """``hystbench daemon`` in a process of its own, serving bench ``flood`` on a loopback port,
    its log lines in ``folder/daemon.stderr``."""

    def __init__(self, folder: Path, *, extra_env: dict[str, str] | None = None) -> None:
        from hystbench.acquisition.zenoh_bus import free_port

        self.endpoint = f"tcp/127.0.0.1:{free_port()}"
        cfg = folder / "daemon.toml"
        cfg.write_text(f'[daemon]\nbench = "{BENCH}"\nlog_dir = "{(folder / "logs").as_posix()}"\n'
                       '[source]\nkind = "sim"\n[estimation]\nenabled = false\n[recording]\nenabled = false\n'
                       f'[zenoh]\nlisten = ["{self.endpoint}"]\n', encoding="utf-8")
        self.stderr_path = folder / "daemon.stderr"
        env = dict(os.environ, STATE_DIRECTORY=str(folder / "state"), PYTHONUNBUFFERED="1", **(extra_env or {}))
        env.pop("NOTIFY_SOCKET", None)
        root = Path(__import__("hystbench").__file__).resolve().parents[1]  # this checkout's code, old or new
        with open(self.stderr_path, "wb") as err:
            self.proc = subprocess.Popen([sys.executable, "-m", "hystbench", "daemon", "--config", str(cfg)],
                                         cwd=root, env=env, stdout=subprocess.DEVNULL, stderr=err)

    def wait_ready(self) -> None:
        """Until ``health`` answers (or the daemon exits, or HANG_S: a failure)."""
        from hystbench.acquisition.zenoh_bus import query_json
        from hystbench.deadline import Deadline

        import zenoh

        deadline = Deadline(HANG_S)
        with zenoh.open(client_config(self.endpoint)) as s:
            while not query_json(s, f"hystbench/{BENCH}/health", timeout_s=deadline.left(1.0)):
                if self.proc.poll() is not None or deadline.expired:
                    raise RuntimeError(f"the daemon did not answer within {deadline.elapsed:.0f} s (exit "
                                       f"{self.proc.poll()}): {self.log()[-2000:]}")

    def memory(self) -> dict[str, int]:
        return memory(self.proc.pid)

    def log(self) -> str:
        return self.stderr_path.read_text(errors="replace")

    def stop(self) -> int | None:
        """SIGTERM, then SIGKILL if it has not exited within HANG_S; its exit status."""
        return stop_process(self.proc, HANG_S)


def payload(size: int) -> bytes:
    """A JSON object of ``size`` bytes for ``cmd/output`` that the daemon refuses (unknown argument)."""
    base = len(json.dumps({"on": False, "pad": ""}))
    return json.dumps({"on": False, "pad": "x" * max(0, size - base)}).encode()


def flood(endpoint: str, sessions: int, commands: int, body: bytes) -> dict[str, int]:
    """``sessions`` sessions, one after the other, each sending ``commands`` commands and
    waiting for each reply (HANG_S at most); how many were refused, accepted, unanswered."""
    import zenoh

    counts = {"refused": 0, "ok": 0, "unanswered": 0}
    for _ in range(sessions):
        with zenoh.open(client_config(endpoint)) as s:
            for _ in range(commands):
                replies = list(s.get(f"hystbench/{BENCH}/cmd/output", payload=body, timeout=HANG_S))
                if not replies or (replies[0].err is not None and replies[0].err.payload.to_bytes() == b"Timeout"):
                    counts["unanswered"] += 1
                else:
                    counts["ok" if replies[0].ok is not None else "refused"] += 1
    return counts


def run(sessions: int = 20, commands: int = 50, size: int = 10_000, rounds: int = 3) -> dict:
    with tempfile.TemporaryDirectory(prefix="hystbench-bench-flood-") as tmp:
        d = Daemon(Path(tmp))
        try:
            d.wait_ready()
            body = payload(size)
            flood(d.endpoint, WARMUP_SESSIONS, commands, body)  # one-time costs (threads, buffers) before the baseline
            before = d.memory()
            after, counts = [], {}
            for _ in range(rounds):
                for k, v in flood(d.endpoint, sessions, commands, body).items():
                    counts[k] = counts.get(k, 0) + v
                after.append(d.memory())
        finally:
            status = d.stop()
        log = d.log()  # after the stop: the last refusals' count is written as the daemon closes
    refused_lines = sum(1 for line in log.splitlines() if "cmd/output refused" in line)
    # past the log budget (zenoh_bus.REFUSALS_LOGGED_PER_S) the refusals are counted in one line each window
    summaries = [int(m.group(1)) for m in re.finditer(r"(\d+) more commands refused, not logged", log)]
    mb = 1e6
    return {
        "benchmark": "command_flood", "sessions": sessions, "commands_per_session": commands,
        "payload_bytes": len(body), "rounds": rounds, "replies": counts, "daemon_exit": status,
        "rss_before_mb": round(before["VmRSS"] / mb, 1), "shmem_before_mb": round(before.get("RssShmem", 0) / mb, 1),
        "rss_after_mb": [round(a["VmRSS"] / mb, 1) for a in after],
        "shmem_after_mb": [round(a.get("RssShmem", 0) / mb, 1) for a in after],
        "growth_mb": round((after[-1]["VmRSS"] - before["VmRSS"]) / mb, 2),
        "growth_per_round_mb": [round((b["VmRSS"] - a["VmRSS"]) / mb, 2) for a, b in zip([before] + after, after)],
        "refused_log_lines": refused_lines, "summary_log_lines": len(summaries),
        "refusals_in_summaries": sum(summaries),
        "threads_before": before["Threads"], "threads_after": [a["Threads"] for a in after],
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks command_flood", description=__doc__.split("\n")[0])
    parser.add_argument("--sessions", type=int, default=20, help="client sessions per round, one after the other")
    parser.add_argument("--commands", type=int, default=50, help="commands per session")
    parser.add_argument("--size", type=int, default=10_000, help="bytes of each command's payload")
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args(argv)
    r = run(args.sessions, args.commands, args.size, args.rounds)
    if args.json:
        print(json.dumps(r, indent=2))
        return 0
    print(f"{args.rounds} x {args.sessions} sessions x {args.commands} commands of {r['payload_bytes']} bytes: "
          f"replies {r['replies']}, {r['refused_log_lines']} 'refused' log lines and {r['summary_log_lines']} "
          f"counting {r['refusals_in_summaries']} more")
    print(f"daemon RSS {r['rss_before_mb']} MB before (shared memory {r['shmem_before_mb']} MB), after each round "
          f"{r['rss_after_mb']} MB (shared memory {r['shmem_after_mb']} MB): {r['growth_mb']:+} MB")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
