"""The bench on zenoh: a documented key space, payload codecs, the daemon's side and a client's.

Key space (``<bench>`` is the daemon's bench name, see docs/zenoh.md)::

    hystbench/<bench>/raw             sample blocks (every channel), binary with a JSON header (below)
    hystbench/<bench>/raw/<channel>   the same, one channel per message (``raw_per_channel = true``)
    hystbench/<bench>/estimate        JSON: delays over each window of whole periods
    hystbench/<bench>/compensator     JSON: the compensator's state
    hystbench/<bench>/status          JSON: events (started, sweep point, errors, config reloaded)
    hystbench/<bench>/stats           JSON: per-stage throughput, latency and drop counters
    hystbench/<bench>/config          queryable: the running configuration
    hystbench/<bench>/health          queryable: state, uptime, counters
    hystbench/<bench>/cmd/<verb>      queryable: start_sweep, stop_sweep, set_excitation, output

Raw payload: the binary framing of the one raw-block codec (:mod:`hystbench.formats.raw_block`,
which the MCAP log's JSON framing shares its header with): ``u32 little-endian header length H``,
``H`` bytes of UTF-8 JSON header, then for each channel of ``header["channels"]`` in order, ``n``
little-endian values of its ``dtype`` (``float32`` or ``float64``).  The header holds
``first_index``, ``n``, ``fs_hz``, ``t0_ns``, ``flags``, ``gap_samples``, ``meta`` (the operating
point and settling) and, per channel, ``name``, ``unit`` and ``dtype``.  Estimates are the JSON of
:class:`hystbench.messages.Estimate` (read them with ``Estimate.from_json``).
"""

from __future__ import annotations

import json
import logging
import queue
import re
import socket
import threading
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, Iterator, Mapping

from ..blocks import SampleBlock
from ..deadline import Deadline
from ..log_budget import LogBudget
from ..errors import BenchError, CommandRefused, ConfigError, NetworkError, NoReply
from .bench_commands import COMMANDS as _COMMAND_ARGS
from .bench_commands import show
from ..messages import json_bytes
from ..formats.raw_block import BINARY_ENCODING, encode_binary

if TYPE_CHECKING:
    import zenoh

__all__ = ["PREFIX", "key", "peer_config", "load_zenoh_config", "ZenohBus",
           "Subscription", "send_command", "query_json", "free_port", "open_session", "ListenError", "COMMANDS",
           "MAX_COMMAND_BYTES", "MAX_COMMAND_DEPTH", "MAX_MESSAGE_BYTES"]

log = logging.getLogger("hystbench.zenoh")

PREFIX = "hystbench"
COMMANDS = tuple(_COMMAND_ARGS)
#: Refused commands logged one by one per second and bench; the rest of a flood is counted in one
#: line (a 20 000-command flood wrote 19 887 lines), and in health's ``commands_refused``.
REFUSALS_LOGGED_PER_S = 10
#: The largest command payload the daemon takes, in bytes (docs/zenoh.md): a larger one is refused
#: before it is copied out of zenoh or parsed.  The largest legal command, a sweep of
#: ``MAX_SWEEP_POINTS`` (1000) frequencies, is about 20 kB of JSON.
MAX_COMMAND_BYTES = 64 * 1024
#: The deepest nesting of arrays and objects a command's JSON may have (a legal one has 2: the
#: object and a sweep's list of frequencies); deeper is refused before it is parsed.
MAX_COMMAND_DEPTH = 8
#: The largest message a serving session (one that listens: the daemon's) puts together from
#: fragments (zenoh's ``transport/link/rx/max_message_size``, 1 GiB by default): a larger one is
#: dropped by zenoh unseen, so no client can make the daemon hold more than this per message.
#: Sixteen times MAX_COMMAND_BYTES, so that a payload a little too big is refused with a reason.
MAX_MESSAGE_BYTES = 1024 * 1024


def key(bench: str, *parts: str) -> str:
    """``hystbench/<bench>/<parts...>``; a bench name must be one key chunk (no '/', '*', '$', '?', '#')."""
    if not bench or any(ch in bench for ch in "/*$?#"):
        raise ConfigError(f"bench name {bench!r} must be non-empty and contain none of / * $ ? #")
    return "/".join((PREFIX, bench, *parts))


# --- configuration ----------------------------------------------------------------------------------
def free_port() -> int:
    """A TCP port on 127.0.0.1 that was free a moment ago (tests: never the default 7447)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


#: Room for bursts of raw blocks: 16 batches of 64 KiB per priority (zenoh's default is 2, 128
#: KiB, which a publisher held up by one 10-ms GIL slice overflows at 16 MB/s), and 5 ms before a
#: put is dropped rather than 1.  Also set in the shipped zenoh*.json5 files.
TX_QUEUE = {"size": {"data": 16, "data_high": 4, "data_low": 4},
            "congestion_control": {"drop": {"wait_before_drop": 5000}}}


def peer_config(*, listen: list[str] | None = None, connect: list[str] | None = None,
                user: str | None = None, password: str | None = None) -> dict:
    """An embedded peer: listens where told (default nowhere), connects where told, no multicast
    scouting and no gossip (so nothing is found that was not configured)."""
    cfg: dict[str, Any] = {"mode": "peer", "listen": {"endpoints": list(listen or [])},
                           "connect": {"endpoints": list(connect or [])},
                           "scouting": {"multicast": {"enabled": False}, "gossip": {"enabled": False}},
                           "transport": {"link": {"tx": {"queue": TX_QUEUE}},
                                         "shared_memory": {"enabled": False}}}
    if user is not None:
        cfg["transport"]["auth"] = {"usrpwd": {"user": user, "password": password or ""}}
    return cfg


def load_zenoh_config(source: str | Path | Mapping | None, *, listen: list[str] | None = None,
                      connect: list[str] | None = None, serve: bool | None = None) -> zenoh.Config:
    """A ``zenoh.Config`` from a json5 file, a dict or (None) :func:`peer_config`; ``listen`` and
    ``connect``, when given, replace the file's endpoints (tests put ephemeral ports there).

    Whatever the source says, two limits are set (docs/zenoh.md, "Memory"):

    - zenoh's shared memory is off: a session that receives a buffer in a peer's shared memory
      keeps that peer's whole segment (16 MiB by default) mapped until the process ends, even after
      the peer has gone (zenoh 1.10, ``ShmReader``; eclipse-zenoh/zenoh#2787), so every local
      client that ever sent the daemon 3 KiB or more added 16 MiB to it for good (issue 26).
      Over loopback TCP instead.
    - a session that serves (``serve``; by default: one that listens on an endpoint, as the
      daemon's does) reassembles messages of at most :data:`MAX_MESSAGE_BYTES`; a client's
      (``serve=False``) keeps zenoh's limit, as a raw block may be larger.

    A session that serves (``serve=True``: the daemon's) but listens nowhere and connects
    somewhere (``[zenoh] listen = []``, ``connect = [a router]``) is opened in zenoh's ``client``
    mode: a zenoh router routes between its clients and its peers, but not between two peers
    that do not gossip (ours do not: nothing is found that was not configured), so two peer
    daemons behind one router would not see each other's clients (docs/zenoh.md, "A fleet").
    A client needs its endpoint reachable when it opens (:func:`open_session` then raises a
    :class:`NetworkError`); it reconnects by itself when that router restarts later.

    A bad endpoint or file is a :class:`ConfigError` of one line naming it."""
    import zenoh

    for role, endpoints in (("listen", listen), ("connect", connect)):
        _check_endpoints(role, endpoints or ())
    where = f"zenoh config {source if source is not None and not isinstance(source, Mapping) else '(built-in)'}"
    try:
        if source is None:
            cfg = zenoh.Config.from_json5(json.dumps(peer_config(listen=listen, connect=connect)))
        else:
            if isinstance(source, Mapping):
                cfg = zenoh.Config.from_json5(json.dumps(dict(source)))
            else:
                path = Path(source)
                if path.is_dir():
                    raise ConfigError(f"{path}: is a folder, not a zenoh config file")
                if not path.is_file():
                    raise ConfigError(f"{path}: zenoh config file not found")
                where = f"zenoh config {path}"
                cfg = zenoh.Config.from_file(str(path))
            if listen is not None:
                cfg.insert_json5("listen/endpoints", json.dumps(list(listen)))
            if connect is not None:
                cfg.insert_json5("connect/endpoints", json.dumps(list(connect)))
        cfg.insert_json5("transport/shared_memory/enabled", "false")
        if serve if serve is not None else bool(_config_endpoints(cfg, "listen")):
            limit = json.loads(cfg.get_json("transport/link/rx/max_message_size"))
            cfg.insert_json5("transport/link/rx/max_message_size", str(min(int(limit), MAX_MESSAGE_BYTES)))
        if serve and _mode(cfg) == "peer" and not _config_endpoints(cfg, "listen") \
                and _config_endpoints(cfg, "connect"):
            cfg.insert_json5("mode", '"client"')  # see the docstring: a router routes for clients
        return cfg
    except ConfigError:
        raise
    except Exception as err:  # zenoh.ZError and friends: say which config
        raise ConfigError(f"{where}: {_plain(str(err))}") from None


#: What a zenoh endpoint looks like, for messages.
_ENDPOINT_FORM = "<protocol>/<address>[?<metadata>][#<config>], e.g. tcp/127.0.0.1:7447"


def _check_endpoints(role: str, endpoints) -> None:
    """Each endpoint as zenoh reads it; a ConfigError naming the first it refuses."""
    import zenoh

    for ep in endpoints:
        try:
            zenoh.Config().insert_json5(f"{role}/endpoints", json.dumps([ep]))
        except Exception as err:
            why = re.sub(r"^line \d+, column \d+: ", "", _plain(str(err)))  # the place in a one-item list
            why = "not a zenoh endpoint" if why.startswith("Endpoints must be of the form") else why
            raise ConfigError(f"{role} endpoint {show(ep, 80)}: {why} ({_ENDPOINT_FORM})") from None
        port = re.fullmatch(r"(?:tcp|udp|tls|quic)/.*:(\d+)(?:[?#].*)?", str(ep))
        if port and not 0 <= int(port.group(1)) <= 65535:  # zenoh takes it; no connection could ever be made
            raise ConfigError(f"{role} endpoint {show(ep, 80)}: port {port.group(1)} is not a TCP/UDP port (0-65535) "
                              f"({_ENDPOINT_FORM})")


def _mode(cfg: zenoh.Config) -> str:
    """The session's zenoh mode: "peer" (zenoh's default), "client" or "router"."""
    return json.loads(cfg.get_json("mode")) or "peer"


def _config_endpoints(cfg: zenoh.Config, role: str) -> list[str]:
    """The endpoints ``cfg`` will ``role`` ("listen", "connect") on in its mode (the value may
    be one list or one per mode)."""
    value = json.loads(cfg.get_json(f"{role}/endpoints"))
    if isinstance(value, dict):
        value = value.get(_mode(cfg)) or []
    return [str(v) for v in value or []]


class ListenError(NetworkError):
    """An endpoint to listen on is taken (another daemon, a zenoh router) or cannot be bound."""


def _plain(message: str) -> str:
    """zenoh's error text as one line for a person: without the Rust source locations it appends
    (`` at /root/.cargo/...rs:61.``), a json5 error's ``Message { msg: "...", location: ... }``
    and a parser's drawing of the line (`` --> 1:9 | ... = expected ...``) as
    ``line L, column C: what``."""
    text = re.sub(r"\s+at\s+\S+\.rs:\d+\.?", "", message)
    wrapped = re.search(r'Message \{ msg: "(.*)", location: '
                        r'(?:Some\(Location \{ line: (\d+), column: (\d+) \}\)|None) \}', text, re.S)
    if wrapped:
        what = wrapped.group(1).replace('\\"', '"')
        text = f"line {wrapped.group(2)}, column {wrapped.group(3)}: {what}" if wrapped.group(2) else what
    drawn = re.search(r"-->\s*(\d+):(\d+)", text)
    said = re.search(r"^\s*=\s*(.+)$", text, re.M)
    if drawn and said:
        text = f"line {drawn.group(1)}, column {drawn.group(2)}: {said.group(1)}"
    return " ".join(text.split())


def open_session(config: zenoh.Config) -> zenoh.Session:
    """A zenoh session; a taken listening port is a :class:`ListenError` naming the endpoint; a
    client whose endpoints cannot be reached a :class:`NetworkError` naming them; any other
    refusal a :class:`ConfigError` of one line naming the endpoints."""
    import zenoh

    try:
        return zenoh.open(config)
    except Exception as err:
        text = _plain(str(err))
        bound = re.search(r"listener bound to (\S+?):\s*\[", text)
        if "Address already in use" in text or bound:
            endpoint = bound.group(1) if bound else "its endpoint"
            why = "address already in use (another hystbench daemon or a zenoh router?)" \
                if "Address already in use" in text else text
            raise ListenError(f"cannot listen on {endpoint}: {why}") from None
        try:
            where = "; ".join(f"{role} {', '.join(eps)}" for role in ("listen", "connect")
                              if (eps := _config_endpoints(config, role)))
        except Exception:
            where = ""
        if text.startswith("Unable to connect to any of"):  # a client: its router (or peer) is not there
            raise NetworkError(f"cannot reach {where.removeprefix('connect ') or 'any endpoint'} (a zenoh "
                               "client connects when it opens: is `hystbench router` running there?)") from None
        raise ConfigError(f"cannot open a zenoh session ({where or 'no endpoints'}): {text}") from None


# --- the daemon's side -----------------------------------------------------------------------------------
class ZenohBus:
    """Publishes a bench's data and serves its queryables and commands.

    ``on_command(verb, args) -> dict`` runs a command (raise :class:`BenchError` to refuse it);
    ``config()`` and ``health()`` answer the queryables.  Publishing never blocks the pipeline:
    raw blocks use congestion control DROP, and a failed put is counted, not raised.
    """

    def __init__(self, bench: str, config: zenoh.Config | None, *,
                 on_command: Callable[[str, dict], dict] | None = None,
                 config_provider: Callable[[], dict] | None = None,
                 health_provider: Callable[[], dict] | None = None, session: zenoh.Session | None = None,
                 per_channel: bool = False) -> None:
        self.bench = bench
        self.per_channel = per_channel
        key(bench)  # validates the name
        self._zconfig = config
        self.on_command, self.config_provider, self.health_provider = on_command, config_provider, health_provider
        self.session = session
        self._own_session = session is None
        self._pubs: dict[str, Any] = {}
        self._lock = threading.Lock()
        self._decls: list[Any] = []
        self.put_errors = 0
        self.published = 0
        self.commands = 0
        self.refused = 0  # commands answered ok: false (one line each, up to the budget)
        #: refusals logged one by one: a flood of them is counted, not written line by line
        self.refusal_log = LogBudget(REFUSALS_LOGGED_PER_S, 1.0)
        self._failures: set[tuple[str, str]] = set()  # (verb, exception) whose traceback was logged

    def open(self) -> "ZenohBus":
        import zenoh

        if self.session is None:
            self.session = open_session(self._zconfig)
        s = self.session
        self._cc_drop = zenoh.CongestionControl.DROP
        self._decls.append(s.declare_queryable(key(self.bench, "config"), self._reply(
            lambda q: self.config_provider() if self.config_provider else {}, key(self.bench, "config"))))
        self._decls.append(s.declare_queryable(key(self.bench, "health"), self._reply(
            lambda q: self.health_provider() if self.health_provider else {}, key(self.bench, "health"))))
        self._decls.append(s.declare_queryable(key(self.bench, "cmd", "*"), self._command))
        return self

    def report_held_refusals(self) -> None:
        """The refusals held back since the last report, in one line (the daemon's loop calls it every
        turn, so a flood's count is in the log a second after it, not at the next refusal)."""
        self._log_held(self.refusal_log.take_held())

    def close(self) -> None:
        self.report_held_refusals()
        for d in self._decls + list(self._pubs.values()):
            try:
                d.undeclare()
            except Exception:
                pass
        self._decls, self._pubs = [], {}
        if self._own_session and self.session is not None:
            self.session.close()
        self.session = None

    def __enter__(self) -> "ZenohBus":
        return self.open()

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _publisher(self, *parts: str, express: bool = False):
        k = "/".join(parts)
        pub = self._pubs.get(k)
        if pub is None:
            import zenoh

            with self._lock:  # several pipeline threads publish
                pub = self._pubs.get(k)
                if pub is None:
                    pub = self._pubs[k] = self.session.declare_publisher(
                        key(self.bench, *parts), congestion_control=zenoh.CongestionControl.DROP, express=express)
        return pub

    def publish_block(self, block: SampleBlock, units: Mapping[str, str] | None = None) -> None:
        """The block on ``raw`` as one message (every channel), or with ``per_channel`` one message
        per channel on ``raw/<channel>``; express (no batching delay).  One put per block is the
        default because each put costs a release and re-acquisition of the GIL: four per block
        doubled the p99 latency at 4 x 1 MS/s (docs/pipeline.md)."""
        if not self.per_channel:
            self._put(self._publisher("raw", express=True), encode_binary(block, None, units), BINARY_ENCODING)
            return
        for name in block.channels:
            self._put(self._publisher("raw", name, express=True), encode_binary(block, [name], units), BINARY_ENCODING)

    def publish(self, topic: str, obj: Any) -> None:
        """A JSON message on ``estimate``, ``compensator``, ``status`` or ``stats``: a dict, or a
        typed message (an :class:`~hystbench.messages.Estimate`) as its ``to_json()``."""
        self._put(self._publisher(topic), json_bytes(obj if isinstance(obj, Mapping) else obj.to_json()),
                  "application/json")

    def _put(self, pub, payload: bytes, encoding: str) -> None:
        try:
            pub.put(payload, encoding=encoding)
            self.published += 1
        except Exception:  # a closed session during shutdown, a full queue: count, never raise
            self.put_errors += 1

    def _reply(self, make: Callable[[Any], dict], own_key: str) -> Callable[[Any], None]:
        """Answers on ``own_key`` (this bench's), not on the query's key: a query on
        ``hystbench/*/health`` then gets one reply per bench, each saying whose it is."""
        def handler(query) -> None:
            with query:
                try:
                    query.reply(own_key, json_bytes(make(query)), encoding="application/json")
                except Exception as err:
                    query.reply_err(json_bytes({"error": str(err)}))
        return handler

    def _command(self, query) -> None:
        """``cmd/<verb>``: answered, always; a refusal is logged in one line naming the verb and why."""
        with query:
            verb = str(query.key_expr).rsplit("/", 1)[-1]
            try:
                args = self._arguments(verb, query.payload)
                if self.on_command is None:
                    raise CommandRefused("this bench takes no commands")
                result = self.on_command(verb, args)
                self.commands += 1
                query.reply(query.key_expr, json_bytes({"ok": True, **(result or {})}), encoding="application/json")
            except (BenchError, ValueError) as err:
                self.refused += 1
                turn = self.refusal_log.admit()
                self._log_held(turn.held)
                if turn.log:
                    log.warning("cmd/%s refused: %s%s", _verb_text(verb), _one_line(str(err)),
                                f" (refusals beyond {self.refusal_log.per_window} a second are counted, not logged: "
                                "health's commands_refused)" if turn.last else "")
                query.reply_err(json_bytes({"ok": False, "error": str(err)}), encoding="application/json")
            except Exception as err:  # never let a command go unanswered (nor kill zenoh's thread)
                self.refused += 1
                kind = (verb if verb in COMMANDS else "?", type(err).__name__)
                first = kind not in self._failures and len(self._failures) < 100
                self._failures.add(kind)  # a traceback once per kind, not once per command a client repeats
                turn = self.refusal_log.admit(always=first)
                self._log_held(turn.held)
                if turn.log:
                    log.error("cmd/%s failed: %s: %s%s", _verb_text(verb), type(err).__name__, _one_line(str(err)),
                              "" if first else " (traceback logged before)", exc_info=first)
                query.reply_err(json_bytes({"ok": False, "error": f"cmd/{_verb_text(verb)} failed: "
                                            f"{type(err).__name__}: {_one_line(str(err))}"}),
                                encoding="application/json")

    @staticmethod
    def _log_held(held: int) -> None:
        if held:
            log.warning("%d more commands refused, not logged one by one (health's commands_refused counts every one)",
                        held)

    @staticmethod
    def _arguments(verb: str, payload) -> dict:
        """A command's arguments: its payload, checked before it is parsed (the verb known, at most
        :data:`MAX_COMMAND_BYTES`, nested at most :data:`MAX_COMMAND_DEPTH` deep), as a JSON object."""
        if verb not in COMMANDS:
            raise ConfigError(f"unknown command {_verb_text(verb)}; known: {', '.join(COMMANDS)}")
        if not payload:
            return {}
        size = len(payload)
        if size > MAX_COMMAND_BYTES:  # before to_bytes(): too big is never copied out of zenoh
            raise ConfigError(f"cmd/{verb}: the payload is {size} bytes, more than the {MAX_COMMAND_BYTES} a "
                              "command may have")
        raw = payload.to_bytes()
        depth = _depth_over(raw, MAX_COMMAND_DEPTH)
        if depth is not None:
            raise ConfigError(f"cmd/{verb}: the payload nests arrays and objects {depth} deep, more than the "
                              f"{MAX_COMMAND_DEPTH} a command may have")
        try:
            args = json.loads(raw)
        except ValueError as err:  # JSONDecodeError, UnicodeDecodeError, an integer of 5000 digits
            raise ConfigError(f"cmd/{verb}: the payload is not JSON: {_one_line(str(err))}") from None
        if not isinstance(args, dict):
            raise ConfigError(f"cmd/{verb}: the payload must be a JSON object, got {type(args).__name__}")
        return args


_STRING = re.compile(rb'"(?:[^"\\]|\\.)*"', re.S)
_BRACKET = re.compile(rb"[\[\]{}]")


def _depth_over(raw: bytes, limit: int) -> int | None:
    """How deep arrays and objects nest in ``raw`` if that is more than ``limit``, else None;
    brackets inside strings do not count, and nothing is parsed (the parser's recursion on a
    payload such as 30 000 ``[`` is what this guards)."""
    if raw.count(b"[") + raw.count(b"{") <= limit:
        return None  # no deeper than the brackets it has
    depth = deepest = 0
    for m in _BRACKET.finditer(_STRING.sub(b'""', raw)):
        if m.group() in b"[{":
            depth += 1
            deepest = max(deepest, depth)
        else:
            depth -= 1
    return deepest if deepest > limit else None


def _verb_text(verb: str) -> str:
    """A verb for a message: as it is if it is one, else quoted and cut short (a client chooses it)."""
    return verb if verb in COMMANDS else show(verb, 40)


def _one_line(text: str, limit: int = 300) -> str:
    """``text`` on one line (a log line per refusal, never one a client's newline splits), cut short."""
    text = text.replace("\r", "\\r").replace("\n", "\\n")
    return text if len(text) <= limit else text[:limit - 3] + "..."


# --- a client's side ---------------------------------------------------------------------------------------
class Subscription:
    """Samples of a key expression, queued (bounded: the oldest are dropped and counted) so that a
    slow reader never holds up zenoh; iterate with a timeout."""

    def __init__(self, session: zenoh.Session, keyexpr: str, maxsize: int = 10_000) -> None:
        self._q: queue.Queue = queue.Queue(maxsize)
        self.dropped = 0
        self._sub = session.declare_subscriber(keyexpr, self._on_sample)

    def _on_sample(self, sample) -> None:
        item = (str(sample.key_expr), sample.payload.to_bytes(), time.monotonic_ns())
        while True:
            try:
                self._q.put_nowait(item)
                return
            except queue.Full:
                try:
                    self._q.get_nowait()
                    self.dropped += 1
                except queue.Empty:
                    pass

    def get(self, timeout_s: float) -> tuple[str, bytes, int] | None:
        """(key, payload, receive time in monotonic ns), or None after ``timeout_s``."""
        try:
            return self._q.get(timeout=max(0.0, timeout_s))
        except queue.Empty:
            return None

    def iter(self, *, count: int | None = None, seconds: float | None = None,
             stop: threading.Event | None = None) -> Iterator[tuple[str, bytes, int]]:
        """What :meth:`get` returns, until ``count`` samples, ``seconds`` or ``stop``: a reader's loop
        that still notices ``stop`` while nothing arrives (it waits 0.2 s at a time)."""
        deadline = Deadline(seconds)
        got = 0
        while (count is None or got < count) and not (stop is not None and stop.is_set()):
            if deadline.expired:
                return
            item = self.get(deadline.left(0.2))
            if item is not None:
                got += 1
                yield item

    def close(self) -> None:
        try:
            self._sub.undeclare()
        except Exception:
            pass


def query_json(session: zenoh.Session, keyexpr: str, payload: Mapping[str, Any] | None = None, *,
               timeout_s: float = 2.0) -> list[dict]:
    """Every reply to a query, decoded: ``{"ok": ...}`` objects; an error reply is included with
    ``ok: False`` (its text as ``error`` when it is no JSON object), for the caller to raise
    :class:`CommandRefused`.  An empty list means nobody answered in time: nobody serves the key,
    access control dropped the query, or the queryable did not answer within ``timeout_s`` (zenoh
    then hands the querier an error reply of its own, ``Timeout``, which is not the daemon's).
    A reply that is no JSON object is a :class:`NetworkError` naming the key: whoever answered
    there does not speak this protocol."""
    kwargs: dict[str, Any] = {"timeout": timeout_s}
    if payload is not None:
        kwargs["payload"] = json.dumps(dict(payload)).encode()
    out = []
    for reply in session.get(keyexpr, **kwargs):
        if reply.ok is not None:
            raw = reply.ok.payload.to_bytes()
            obj = _json_object(raw)
            if obj is None:
                raise NetworkError(f"{keyexpr}: the reply is not a JSON object: {_preview(raw)} "
                                   "(does something other than a hystbench daemon serve this key?)")
            out.append(obj)
            continue
        raw = reply.err.payload.to_bytes()
        if raw == _ZENOH_TIMEOUT:
            continue  # zenoh's own, not the daemon's: nobody answered within timeout_s
        obj = _json_object(raw)
        if obj is not None and "error" in obj:  # the daemon's {"ok": false, "error": ...}
            out.append({**obj, "ok": False})
        else:  # someone else's refusal: its text is the reason
            out.append({"ok": False, "error": raw.decode("utf-8", "replace")})
    return out


#: What zenoh itself hands the querier, as an error reply, when a queryable it routed the query
#: to did not answer within the timeout (a busy daemon, or access control dropping the query).
_ZENOH_TIMEOUT = b"Timeout"


def _json_object(raw: bytes) -> dict | None:
    """``raw`` as a JSON object, or None if it is none (not UTF-8, not JSON, not an object)."""
    try:
        obj = json.loads(raw)
    except ValueError:  # JSONDecodeError and UnicodeDecodeError are both ValueErrors
        return None
    return obj if isinstance(obj, dict) else None


def _preview(raw: bytes, limit: int = 80) -> str:
    """The start of a payload for a message (repr: control characters shown, not printed)."""
    text = repr(raw[:limit].decode("utf-8", "replace"))
    return text + (f" ... ({len(raw)} bytes)" if len(raw) > limit else "")


def send_command(session: zenoh.Session, bench: str, verb: str, args: Mapping[str, Any] | None = None, *,
                 timeout_s: float = 2.0) -> dict:
    """Run ``cmd/<verb>`` on a bench; raises CommandRefused if refused, NoReply if unanswered (timeout, or
    denied by access control: a denied query is dropped, not answered)."""
    replies = query_json(session, key(bench, "cmd", verb), args or {}, timeout_s=timeout_s)
    if not replies:
        raise NoReply(f"bench {bench!r}: no reply to cmd/{verb} within {timeout_s:g} s "
                         "(daemon not reachable, or access control denies this subject)")
    r = replies[0]
    if not r.get("ok"):
        raise CommandRefused(f"bench {bench!r}: cmd/{verb} refused: {r.get('error')}", r)
    return r
