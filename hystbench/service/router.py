"""A zenoh router for a fleet of benches: ``hystbench router`` (docs/zenoh.md, "A fleet").

A session of zenoh's own in ``router`` mode: zenoh does the routing, hystbench only builds its
configuration the way :func:`~hystbench.acquisition.zenoh_bus.peer_config` does (explicit
endpoints, no multicast scouting, no gossip, no shared memory), so that the router is reached
only where it was told to listen and finds nothing it was not told about.  Daemons connect to it
with ``[zenoh] connect = ["tcp/ROUTER:7447"]`` and ``listen = []`` (they are then its clients);
``hystbench watch`` and ``hystbench ctl`` connect to it with ``--connect``.
"""

from __future__ import annotations

import threading
from pathlib import Path
from typing import TYPE_CHECKING, Sequence

from ..acquisition.zenoh_bus import TX_QUEUE, _config_endpoints, load_zenoh_config, open_session

if TYPE_CHECKING:
    import zenoh

__all__ = ["DEFAULT_LISTEN", "router_config", "Router"]

#: Where a router listens when not told: zenoh's usual port, this machine only (give
#: ``--listen tcp/0.0.0.0:7447`` or the PC's address for benches on other PCs).
DEFAULT_LISTEN = "tcp/127.0.0.1:7447"


def router_config(*, listen: Sequence[str] | None = None, connect: Sequence[str] | None = None) -> dict:
    """A router's zenoh configuration: listens on ``listen`` (default :data:`DEFAULT_LISTEN`),
    connects to ``connect`` (another router, default none), finds nothing by itself."""
    return {"mode": "router", "listen": {"endpoints": list(listen or [DEFAULT_LISTEN])},
            "connect": {"endpoints": list(connect or [])},
            "scouting": {"multicast": {"enabled": False}, "gossip": {"enabled": False}},
            "transport": {"link": {"tx": {"queue": TX_QUEUE}}, "shared_memory": {"enabled": False}}}


class Router:
    """A running zenoh router (a context manager): :meth:`open`, then :meth:`close`, or
    :meth:`run` until ``stop`` is set.

    ``config_file``: a zenoh json5 file (access control, TLS, ...), opened in router mode whatever
    its ``mode`` says; ``listen``, when given, replaces its listen endpoints.  A taken port is a
    :class:`~hystbench.acquisition.zenoh_bus.ListenError` naming the endpoint."""

    def __init__(self, listen: Sequence[str] | None = None, *, config_file: str | Path | None = None) -> None:
        self.config_file = config_file
        if config_file is None:
            cfg = load_zenoh_config(router_config(listen=listen), serve=False)
        else:
            cfg = load_zenoh_config(config_file, listen=list(listen) if listen else None, serve=False)
            cfg.insert_json5("mode", '"router"')
        self._zconfig = cfg
        self.endpoints: list[str] = _config_endpoints(cfg, "listen")
        self.session: zenoh.Session | None = None

    def open(self) -> "Router":
        self.session = open_session(self._zconfig)
        return self

    def close(self) -> None:
        if self.session is not None:
            self.session.close()
            self.session = None

    def __enter__(self) -> "Router":
        return self.open()

    def __exit__(self, *exc: object) -> None:
        self.close()

    @property
    def zid(self) -> str:
        return str(self.session.zid()) if self.session is not None else ""

    def run(self, stop: threading.Event) -> None:
        """Route until ``stop`` is set (the command line sets it on SIGINT or SIGTERM)."""
        if self.session is None:
            self.open()
        try:
            stop.wait()
        finally:
            self.close()
