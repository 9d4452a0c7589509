"""``hystbench emulate``: the emulated bench instruments, standalone.

Prints on the FIRST line of stdout one JSON object saying where each instrument listens, then runs
until SIGINT or SIGTERM.  ``python -m hystbench emulate`` is the same command.
"""

from __future__ import annotations

import argparse
import json
import signal
import sys
import threading

from .args import path_arg

__all__ = ["register", "cmd_emulate"]


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the bench commands to the CLI's subparsers."""
    p = subparsers.add_parser("emulate", help="run the emulated bench instruments until SIGINT/SIGTERM",
                              description="Prints on the first line of stdout one JSON object saying where each instrument "
                                          "listens, then runs until SIGINT or SIGTERM. 'python -m hystbench "
                                          "emulate' is the same command.")
    p.add_argument("--config", type=path_arg, default=None, help="bench file (default: the shipped config/bench.toml)")
    p.set_defaults(func=cmd_emulate)


def cmd_emulate(args: argparse.Namespace) -> int:
    """`hystbench emulate`: the bench's instruments emulated on real transports, so the drivers,
    the daemon and ``ctl`` can be tried with no hardware; prints their addresses (JSON), runs until
    SIGINT/SIGTERM."""
    from ..drivers.protocols.bench_config import load_bench_config
    from ..sim_backend.emulators.bench import EmulatedBench

    config = load_bench_config(args.config)
    stop = threading.Event()
    previous = {sig: signal.signal(sig, lambda *_: stop.set()) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        with EmulatedBench(config) as emu:
            print(json.dumps(emu.addresses), flush=True)
            can = emu.addresses["flux_integrator"]
            if can["can_interface"] == "virtual":
                print(f"note: the flux integrator is on python-can virtual channel {can['can_channel']!r}, "
                      "reachable only from this process; set [flux_integrator] interface = \"socketcan\" and "
                      "channel = \"vcan0\" to share it", file=sys.stderr, flush=True)
            while not stop.wait(0.2):
                pass
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    return 0
