"""systemd's notify protocol without a dependency: one datagram to ``$NOTIFY_SOCKET`` per message.

``READY=1`` once serving, ``RELOADING=1`` + ``MONOTONIC_USEC`` around a SIGHUP reload,
``STOPPING=1`` on the way out, ``WATCHDOG=1`` at least every half ``WatchdogSec``, ``STATUS=...``
for ``systemctl status``.  Outside systemd (no ``$NOTIFY_SOCKET``) every call is a no-op.
"""

from __future__ import annotations

import os
import socket
import time

__all__ = ["notify", "watchdog_interval_s", "Notifier"]


def notify(*fields: str, timeout_s: float = 1.0) -> bool:
    """Send ``fields`` (e.g. ``"READY=1"``, ``"STATUS=recording"``); False if there is no socket
    or the send failed (never raises: the service must not die of its supervisor)."""
    addr = os.environ.get("NOTIFY_SOCKET")
    if not addr or not fields:
        return False
    if addr.startswith("@"):  # abstract namespace
        addr = "\0" + addr[1:]
    try:
        with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM | socket.SOCK_CLOEXEC) as s:
            s.settimeout(timeout_s)
            s.connect(addr)
            s.sendall("\n".join(fields).encode())
        return True
    except OSError:
        return False


def watchdog_interval_s() -> float | None:
    """Half of systemd's ``WatchdogSec`` (from ``$WATCHDOG_USEC``), or None if there is no watchdog
    for this process (unset, or ``$WATCHDOG_PID`` names another process)."""
    usec = os.environ.get("WATCHDOG_USEC")
    pid = os.environ.get("WATCHDOG_PID")
    if not usec or (pid and pid.isdigit() and int(pid) != os.getpid()):
        return None
    try:
        value = int(usec)
    except ValueError:
        return None
    return value / 2e6 if value > 0 else None


class Notifier:
    """The daemon's side: remembers the watchdog period and pings only when it is due."""

    def __init__(self) -> None:
        self.watchdog_s = watchdog_interval_s()
        self._last_ping = 0.0

    def ready(self, status: str = "") -> bool:
        return notify("READY=1", *([f"STATUS={status}"] if status else []))

    def reloading(self) -> bool:
        return notify("RELOADING=1", f"MONOTONIC_USEC={time.clock_gettime_ns(time.CLOCK_MONOTONIC) // 1000}")

    def stopping(self, status: str = "") -> bool:
        return notify("STOPPING=1", *([f"STATUS={status}"] if status else []))

    def status(self, text: str) -> bool:
        return notify(f"STATUS={text}")

    def ping(self, now: float | None = None) -> bool:
        """``WATCHDOG=1`` if a watchdog is armed and half its period has passed since the last."""
        if self.watchdog_s is None:
            return False
        now = time.monotonic() if now is None else now
        if now - self._last_ping < self.watchdog_s:
            return False
        self._last_ping = now
        return notify("WATCHDOG=1")
