"""What the daemon tests share: the daemon as a real process, and its health asked until a condition holds."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
from pathlib import Path

from hystbench.acquisition.zenoh_bus import query_json
from hystbench.deadline import Deadline

ROOT = Path(__file__).resolve().parents[2]
HANG_S = 60.0  # a safety timeout: waits end on their event, only a hang takes this long


def health_when(session, bench: str, cond) -> dict:
    """The daemon's health once ``cond(health)`` holds, asked until it does (a daemon that has just
    started or reloaded may not answer, or may not have produced a sample yet)."""
    deadline, last = Deadline(HANG_S), None
    while not deadline.expired:
        got = query_json(session, f"hystbench/{bench}/health", timeout_s=1.0)
        if got and cond(got[0]):
            return got[0]
        last = got or last
    raise AssertionError(f"hystbench/{bench}/health never met the condition; last: {last}")


class Daemon:
    """The daemon in a subprocess with a notify socket of our own."""

    def __init__(self, tmp: Path, config: Path | str, *, state: Path | None = None, name: str = "",
                 python: tuple[str, ...] = ("-m", "hystbench")) -> None:
        """``python``: what runs ``hystbench daemon --config CONFIG`` (``-c SCRIPT``: a script that
        injects a fault first, then calls ``hystbench.cli.main.main(sys.argv[1:])``)."""
        self.sock_path = tmp / f"notify{name}.sock"
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        self.sock.bind(str(self.sock_path))
        self.messages: list[str] = []
        self.stderr_path = tmp / f"daemon{name}.stderr"
        env = dict(os.environ, NOTIFY_SOCKET=str(self.sock_path), WATCHDOG_USEC="400000", PYTHONUNBUFFERED="1",
                   STATE_DIRECTORY=str(state or tmp / "state"))
        env.pop("WATCHDOG_PID", None)
        self.proc = subprocess.Popen([sys.executable, *python, "daemon",
                                      "--config", str(config)], cwd=ROOT, env=env,
                                     stdout=subprocess.DEVNULL, stderr=open(self.stderr_path, "wb"))

    def wait_for(self, field: str) -> None:
        """Read notifications until one holds ``field`` (or the daemon exits: a failure).  However
        long the daemon takes on a busy machine: the timeout only turns a hang into a failure."""
        deadline = Deadline(HANG_S)
        while not deadline.expired:
            self.sock.settimeout(max(0.01, deadline.left(0.5)))
            try:
                msg = self.sock.recv(4096).decode()
            except socket.timeout:
                if self.proc.poll() is not None:
                    break
                continue
            self.messages.append(msg)
            if field in msg.split("\n"):
                return
        raise AssertionError(f"no {field} within {deadline.elapsed:.0f} s; got {self.messages[-5:]}; "
                             f"exit {self.proc.poll()}; stderr: {self.stderr()[-2000:]}")

    def stderr(self) -> str:
        return self.stderr_path.read_text(errors="replace")

    def close(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait(timeout=10)
        self.sock.close()
