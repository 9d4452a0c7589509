"""``hystbench router``: a zenoh router for a fleet of benches (zenoh's routing, not ours).

Prints on its first line of stdout where it listens (and, with ``--foxglove``, on its second where
the Foxglove view of every bench is served), then routes until SIGINT or SIGTERM (exit 0; 1, saying
so, if its shutdown outlasts :data:`STOP_S`).  A taken port is one line on stderr naming ``--listen``
or ``--foxglove`` (exit 2).
"""

from __future__ import annotations

import argparse
import signal
import threading

from .args import path_arg

__all__ = ["register", "cmd_router", "foxglove_address"]

#: SIGINT or SIGTERM ends the router within this long (s), whatever closing its session or view hangs on
STOP_S = 5.0
#: where ``--foxglove PORT`` serves when no host is given: this PC only (the server has no access control)
FOXGLOVE_HOST = "127.0.0.1"


def foxglove_address(text: str) -> tuple[str, int]:
    """``[HOST:]PORT`` as (host, port); anything else is a one-line error naming ``--foxglove``."""
    host, _, port = text.rpartition(":")
    host = host.strip("[]") or FOXGLOVE_HOST
    if not port.isdigit() or not 0 <= int(port) <= 65535 or any(c.isspace() for c in host):
        raise argparse.ArgumentTypeError(f"{text!r} is not [HOST:]PORT (e.g. 8765 or 127.0.0.1:8765)")
    return host, int(port)


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add ``router`` to the CLI's subparsers."""
    p = subparsers.add_parser("router", help="run a zenoh router that daemons, watch and ctl connect to (a fleet)",
                              description="A zenoh router: daemons connect to it ([zenoh] connect = [ENDPOINT], "
                                          "listen = []), and so do `hystbench watch` and `hystbench ctl` "
                                          "(--connect ENDPOINT). Runs until SIGINT or SIGTERM.")
    p.add_argument("--listen", action="append", metavar="ENDPOINT",
                   help="endpoint to listen on (default tcp/127.0.0.1:7447: this PC only; tcp/0.0.0.0:7447 for "
                        "benches on other PCs; repeatable)")
    p.add_argument("--config", type=path_arg, metavar="FILE",
                   help="zenoh json5 config (access control, TLS); opened in router mode, --listen replaces its "
                        "listen endpoints")
    p.add_argument("--foxglove", type=foxglove_address, metavar="[HOST:]PORT",
                   help="also serve one Foxglove WebSocket view of every bench reached through the router "
                        f"(/<bench>/estimate, /compensator, /status, /stats); HOST defaults to {FOXGLOVE_HOST}")
    p.set_defaults(func=cmd_router)


def cmd_router(args: argparse.Namespace) -> int:
    """`hystbench router`: open the router, say where it listens, route until a signal."""
    from ..acquisition.zenoh_bus import ListenError
    from ..errors import ConfigError
    from ..service.router import Router
    from ..service.shutdown import end_after

    router = Router(args.listen, config_file=args.config)
    try:
        router.open()
    except ListenError as err:
        raise ConfigError(f"{err}; choose another --listen") from None
    view = None
    if getattr(args, "foxglove", None) is not None:
        from ..service.foxglove_live import FoxgloveFleet

        try:
            view = FoxgloveFleet(*args.foxglove).start(router.session)
        except BaseException:
            router.close()
            raise
    stop = threading.Event()

    def on_signal(signum: int, _frame: object) -> None:
        if not stop.is_set():  # closing the view and the session may block: bounded
            end_after(STOP_S, signal.Signals(signum).name, "the router")
        stop.set()

    previous = {sig: signal.signal(sig, on_signal) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        print(f"hystbench router: listening on {', '.join(router.endpoints) or '(nothing)'} (zid {router.zid}); "
              "daemons: [zenoh] connect = [that endpoint], listen = []; SIGINT or SIGTERM stops it", flush=True)
        if view is not None:
            print(f"hystbench router: Foxglove view of every bench on {view.url}", flush=True)
        router.run(stop)
    finally:
        if view is not None:
            view.close()
        router.close()
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    return 0
