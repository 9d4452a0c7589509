"""``hystbench router``: a zenoh router for a fleet of benches (zenoh's routing, not ours).

Prints on its first line of stdout where it listens, then routes until SIGINT or SIGTERM (exit
0).  A taken port is one line on stderr naming ``--listen`` (exit 2).
"""

from __future__ import annotations

import argparse
import signal
import threading

from .args import path_arg

__all__ = ["register", "cmd_router"]


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
    p.set_defaults(func=cmd_router)


def cmd_router(args: argparse.Namespace) -> int:
    """`hystbench router`: open the router, say where it listens, route until a signal."""
    from ..acquisition.zenoh_bus import ListenError
    from ..errors import ConfigError
    from ..service.router import Router

    router = Router(args.listen, config_file=args.config)
    try:
        router.open()
    except ListenError as err:
        raise ConfigError(f"{err}; choose another --listen") from None
    stop = threading.Event()
    previous = {sig: signal.signal(sig, lambda *_: stop.set()) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        print(f"hystbench router: listening on {', '.join(router.endpoints) or '(nothing)'} (zid {router.zid}); "
              "daemons: [zenoh] connect = [that endpoint], listen = []; SIGINT or SIGTERM stops it", flush=True)
        router.run(stop)
    finally:
        router.close()
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    return 0
