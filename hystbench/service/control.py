"""Driving a running bench over zenoh: its commands (``cmd/<verb>``) and queries (``health``,
``config``), as ``hystbench ctl`` and the demo send them, so nobody needs Python to drive a bench.

A refusal (the daemon answered ``ok: false``) is :class:`~hystbench.errors.CommandRefused`, with
the daemon's reason and reply; no answer within the timeout is :class:`~hystbench.errors.NoReply`,
naming the key expression and the endpoint (no daemon there, a different bench name, or access
control dropping the query).
"""

from __future__ import annotations

import json
import threading
from typing import TYPE_CHECKING, Any, Mapping, Sequence

from ..acquisition.zenoh_bus import (COMMANDS, MAX_COMMAND_BYTES, PREFIX, _json_object, key, load_zenoh_config,
                                     open_session, query_json)
from ..deadline import Deadline
from ..errors import CommandRefused, ConfigError, NoReply

if TYPE_CHECKING:
    import zenoh

__all__ = ["DEFAULT_CONNECT", "client_config", "QUERIES", "FLEET_VERBS", "MAX_TIMEOUT_S", "BenchControl", "open_client",
           "describe_endpoint", "is_bench_pattern", "bench_pattern", "fleet_health"]

DEFAULT_CONNECT = "tcp/127.0.0.1:7447"
#: queryables that take no arguments and change nothing
QUERIES = ("health", "config")
#: the longest a request may wait (a day): a bound, so that no timeout overflows zenoh's clock
MAX_TIMEOUT_S = 86_400.0
_RETRY_S = 0.05  # a session still connecting answers "nobody" at once: ask again after this
#: what may go to several benches at once (``--bench '*'``): the read-only ones; a command goes to one bench
FLEET_VERBS = ("status", "health")


def describe_endpoint(connect: Sequence[str] | None, zenoh_config: str | None) -> str:
    """How this client reaches the daemon, for messages ('tcp/127.0.0.1:7447', 'zenoh config X')."""
    if connect:
        return ", ".join(connect)
    return f"the endpoints of zenoh config {zenoh_config}" if zenoh_config else DEFAULT_CONNECT


def client_config(connect: Sequence[str] | None = None, zenoh_config: str | None = None) -> zenoh.Config:
    """A client's configuration: a peer that listens nowhere and connects to ``connect`` (default
    :data:`DEFAULT_CONNECT`, or the endpoints of ``zenoh_config`` when one is given).  Not a
    serving one: it takes messages as large as zenoh does (a raw block may be megabytes).  A bad
    endpoint or file is a one-line :class:`~hystbench.errors.ConfigError` naming it."""
    endpoints = list(connect or ([] if zenoh_config else [DEFAULT_CONNECT]))
    return load_zenoh_config(zenoh_config, listen=[] if not zenoh_config else None, connect=endpoints or None,
                             serve=False)


def open_client(connect: Sequence[str] | None = None, zenoh_config: str | None = None) -> zenoh.Session:
    """A session of :func:`client_config`."""
    return open_session(client_config(connect, zenoh_config))


class BenchControl:
    """One bench's commands and queries over one client session (a context manager).

    ``session`` reuses an open session (not closed here); otherwise one is opened from
    ``connect`` / ``zenoh_config``.  ``timeout_s`` bounds each request."""

    def __init__(self, bench: str = "bench1", *, connect: Sequence[str] | None = None,
                 zenoh_config: str | None = None, timeout_s: float = 2.0,
                 session: zenoh.Session | None = None) -> None:
        key(bench)  # a bad name is refused before anything is opened
        if not 0 < timeout_s <= MAX_TIMEOUT_S:
            raise ConfigError(f"timeout must be in (0, {MAX_TIMEOUT_S:g}] s, got {timeout_s!r}")
        self.bench, self.timeout_s = bench, float(timeout_s)
        self.endpoint = describe_endpoint(connect, zenoh_config)
        self._own = session is None
        self.session = open_client(connect, zenoh_config) if session is None else session

    def __enter__(self) -> "BenchControl":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        if self._own and self.session is not None:
            self.session.close()
        self.session = None

    def keyexpr(self, verb: str) -> str:
        """``hystbench/<bench>/cmd/<verb>`` for a command, ``hystbench/<bench>/<verb>`` for a query."""
        return key(self.bench, verb) if verb in QUERIES else key(self.bench, "cmd", verb)

    def request(self, verb: str, args: Mapping[str, Any] | None = None) -> dict:
        """Send ``verb`` (a command with its JSON arguments, or a query) and return the reply.

        Asked again while the answer is "nobody" and time is left (a fresh session may not yet
        know the daemon's queryables; such a query reached no one, so nothing runs twice)."""
        if verb not in COMMANDS and verb not in QUERIES:
            raise ConfigError(f"unknown verb {verb!r}; known: {', '.join((*COMMANDS, *QUERIES))}")
        k = self.keyexpr(verb)
        payload = dict(args or {}) if verb in COMMANDS else None
        size = len(json.dumps(payload).encode()) if payload is not None else 0
        if size > MAX_COMMAND_BYTES:  # the daemon would refuse it (or zenoh drop it: no reply at all)
            raise ConfigError(f"{verb}: the arguments are {size} bytes of JSON, more than the {MAX_COMMAND_BYTES} "
                              "a daemon takes")
        deadline = Deadline(self.timeout_s)
        pause = threading.Event()
        while True:
            replies = query_json(self.session, k, payload, timeout_s=max(deadline.left(), 0.01))
            if replies:
                break
            if deadline.left() <= _RETRY_S:
                raise NoReply(f"no daemon answered on {k} via {self.endpoint} within {self.timeout_s:g} s "
                              f"(is `hystbench daemon` running with [daemon] bench = {self.bench!r} and that "
                              "endpoint? access control also drops a query it denies)")
            pause.wait(_RETRY_S)
        reply = replies[0]
        if not reply.get("ok", True):
            raise CommandRefused(f"bench {self.bench!r} refused {verb}: {reply.get('error')}", reply)
        return reply

    def health(self) -> dict:
        return self.request("health")

    def config(self) -> dict:
        return self.request("config")


# --- several benches at once (``hystbench ctl --bench '*' status``) ------------------------------------
def is_bench_pattern(bench: str) -> bool:
    """Whether ``bench`` names several benches (it has a ``*``)."""
    return "*" in bench


def bench_pattern(bench: str) -> str:
    """``bench`` as one chunk of a zenoh key expression: ``*`` alone is every bench, a ``*`` inside
    a name (``lab-*``) any text there (zenoh's ``$*``); a :class:`ConfigError` if it cannot be one."""
    if not bench or any(ch in bench for ch in "/$?#"):
        raise ConfigError(f"bench pattern {bench!r} must be non-empty and contain none of / $ ? # "
                          "(* stands for any text)")
    chunk = bench if bench == "*" else bench.replace("*", "$*")
    import zenoh

    try:
        zenoh.KeyExpr(f"{PREFIX}/{chunk}/health")
    except Exception:
        raise ConfigError(f"bench pattern {bench!r} is not a zenoh key chunk") from None
    return chunk


def fleet_health(pattern: str, session: zenoh.Session, *, timeout_s: float = 2.0) -> dict[str, dict | None]:
    """The health of every bench matching ``pattern`` (:func:`bench_pattern`) that answers within
    ``timeout_s``: ``{bench: health}``, sorted by name.  A bench whose daemon is alive (its
    liveliness token ``hystbench/<bench>/alive`` is seen) but whose health did not come in time
    (access control, a daemon too busy) is listed with None.  Asked again while nobody has
    answered, or an alive bench has not, and time is left: a fresh session may not know every
    daemon yet.  Bounded by ``timeout_s`` in every case."""
    import zenoh

    from .instance import ALIVE

    if not 0 < timeout_s <= MAX_TIMEOUT_S:
        raise ConfigError(f"timeout must be in (0, {MAX_TIMEOUT_S:g}] s, got {timeout_s!r}")
    chunk = bench_pattern(pattern)
    deadline, pause = Deadline(timeout_s), threading.Event()
    alive: set[str] = set()
    answered: dict[str, dict] = {}
    while True:
        for reply in session.liveliness().get(f"{PREFIX}/{chunk}/{ALIVE}", timeout=max(deadline.left(0.5), 0.01)):
            if reply.ok is not None:
                alive.add(str(reply.ok.key_expr).split("/")[1])
        for reply in session.get(f"{PREFIX}/{chunk}/health", target=zenoh.QueryTarget.ALL,
                                 consolidation=zenoh.ConsolidationMode.NONE, timeout=max(deadline.left(), 0.01)):
            if reply.ok is not None:
                obj = _json_object(reply.ok.payload.to_bytes())
                if obj is not None:  # whose: the bench it names (daemons before issue 31 replied on the query's key)
                    answered[str(obj.get("bench") or str(reply.ok.key_expr).split("/")[1])] = obj
        if (answered and alive <= set(answered)) or deadline.left() <= _RETRY_S:
            break
        pause.wait(_RETRY_S)
    return {b: answered.get(b) for b in sorted(alive | set(answered))}
