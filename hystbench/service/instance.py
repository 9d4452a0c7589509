"""One daemon per bench: where its state lives, a lock file, and a zenoh liveliness token.

Two daemons of one bench would fight over the same serial lines, Modbus unit and CAN node.  The
daemon therefore takes, before it opens anything else:

- a lock per bench in its state directory (``<state>/<bench>.lock``, ``fcntl.flock``: released by
  the kernel when the process ends, even after ``kill -9``), holding its PID and zenoh endpoints,
  so a second daemon on the same machine is refused with the first one's PID and endpoints;
- a zenoh liveliness token ``hystbench/<bench>/alive``: a daemon that can reach another one of
  the same bench over zenoh (another machine, another state directory) is refused too.

State directory: ``$STATE_DIRECTORY`` (systemd's ``StateDirectory=hystbench``: /var/lib/hystbench),
else ``$XDG_STATE_HOME/hystbench``, else ``~/.local/state/hystbench``.  The logs go to its ``logs``
folder unless ``[daemon] log_dir`` says otherwise.
"""

from __future__ import annotations

import fcntl
import json
import os
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ..errors import ConfigError

if TYPE_CHECKING:
    import zenoh

__all__ = ["state_dir", "default_log_dir", "BenchLock", "claim_on_zenoh", "ALIVE"]

ALIVE = "alive"  #: hystbench/<bench>/alive: the liveliness token of the bench's daemon


def state_dir() -> tuple[Path, str]:
    """The daemon's state directory and where that choice came from (for the start-up message)."""
    systemd = os.environ.get("STATE_DIRECTORY", "")
    if systemd:
        return Path(systemd.split(":")[0]), "$STATE_DIRECTORY"
    xdg = os.environ.get("XDG_STATE_HOME", "")
    if xdg and Path(xdg).is_absolute():
        return Path(xdg) / "hystbench", "$XDG_STATE_HOME/hystbench"
    return Path.home() / ".local" / "state" / "hystbench", "~/.local/state/hystbench"


def default_log_dir() -> tuple[Path, str]:
    """(folder, how to say it) for a daemon's logs when its file names none: beside the bench lock
    in the state directory, never the working directory a service happens to start in."""
    folder, why = state_dir()
    return folder / "logs", f"{why}/logs"


class BenchLock:
    """``with BenchLock(bench, endpoints, config):`` -- or :meth:`acquire` / :meth:`release`.

    A second holder is refused with a :class:`ConfigError` naming the first one's PID, zenoh
    endpoints, configuration file and the lock file."""

    def __init__(self, bench: str, *, endpoints: list[str] | None = None, config: str = "",
                 folder: Path | None = None) -> None:
        self.bench = bench
        self.path = (folder or state_dir()[0]) / f"{bench}.lock"
        self.info = {"pid": os.getpid(), "bench": bench, "endpoints": list(endpoints or []), "config": config,
                     "started_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())}
        self._fd: int | None = None

    def acquire(self) -> "BenchLock":
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
        except OSError as err:
            raise ConfigError(f"cannot create the lock file {self.path}: {err.strerror}; set $STATE_DIRECTORY "
                              "or $XDG_STATE_HOME to a writable folder") from err
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            other = _read_info(fd)
            os.close(fd)
            raise ConfigError(f"bench {self.bench!r} is already served by {_describe(other)} (lock {self.path}); "
                              "stop that daemon first, or give this one another [daemon] bench") from None
        os.ftruncate(fd, 0)
        os.pwrite(fd, (json.dumps(self.info) + "\n").encode(), 0)
        self._fd = fd
        return self

    def release(self) -> None:
        if self._fd is not None:
            try:
                os.ftruncate(self._fd, 0)
            except OSError:
                pass
            os.close(self._fd)  # closing the descriptor releases the flock
            self._fd = None

    def __enter__(self) -> "BenchLock":
        return self.acquire()

    def __exit__(self, *exc: object) -> None:
        self.release()


def _read_info(fd: int) -> dict[str, Any]:
    try:
        return json.loads(os.pread(fd, 4096, 0).decode() or "{}")
    except (OSError, ValueError):
        return {}


def _describe(info: dict[str, Any]) -> str:
    pid = info.get("pid", "?")
    ends = ", ".join(info.get("endpoints") or []) or "listening nowhere"
    cfg = info.get("config") or "built-in defaults"
    return f"PID {pid} (zenoh {ends}; config {cfg})"


def claim_on_zenoh(session: zenoh.Session, bench: str, *, timeout_s: float = 1.0) -> zenoh.LivelinessToken:
    """Refuse if a daemon of ``bench`` is alive on the zenoh network ``session`` reaches; else
    declare this daemon's liveliness token (returned: keep it, undeclare it at stop)."""
    from ..acquisition.zenoh_bus import key, query_json

    alive = key(bench, ALIVE)
    replies = [r for r in session.liveliness().get(alive, timeout=timeout_s) if r.ok is not None]
    if replies:
        health = query_json(session, key(bench, "health"), timeout_s=timeout_s)
        h = health[0] if health else {}
        info = {"pid": h.get("pid", "?"), "endpoints": h.get("listen") or [], "config": h.get("config", "")}
        raise ConfigError(f"bench {bench!r} is already served on the zenoh network by {_describe(info)}; "
                          "stop that daemon first, or give this one another [daemon] bench")
    return session.liveliness().declare_token(alive)
