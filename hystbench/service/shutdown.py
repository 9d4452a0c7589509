"""A process that was told to stop ends within a bound, whatever its shutdown hangs on.

A stop closes libraries we do not control (a zenoh session, a WebSocket server, a driver's port);
any of them can block.  The daemon and the router start :func:`end_after` when SIGTERM or SIGINT
comes: if the process is still there after ``bound_s``, it says so and exits at once (status 1).
The kernel frees its ports and locks; for a daemon, with the heartbeat gone, the amplifier's
watchdog switches the output off (the drivers tried first, in the stop that is hanging).
"""

from __future__ import annotations

import logging
import os
import threading

__all__ = ["end_after"]

log = logging.getLogger("hystbench.shutdown")


def end_after(bound_s: float, signame: str, what: str, setting: str = "") -> threading.Timer:
    """Start the bound: ``what`` names what did not stop ("the service"), ``setting`` where the bound is
    set ("[daemon] stop_timeout_s").  A daemon thread, so it never holds the process up itself."""
    timer = threading.Timer(bound_s, _end_now, args=(bound_s, signame, what, setting))
    timer.daemon = True
    timer.start()
    return timer


def _end_now(bound_s: float, signame: str, what: str, setting: str) -> None:
    log.error("%s: %s did not stop within %g s%s; exiting now", signame, what, bound_s, f" ({setting})" if setting else "")
    logging.shutdown()
    os._exit(1)
