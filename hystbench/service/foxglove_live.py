"""The daemon's live view in Foxglove: a WebSocket server (the ``foxglove-sdk`` package, protocol
``foxglove.sdk.v1``) fed by the pipeline's messages and its raw blocks (``[foxglove]`` in the
daemon file; docs/foxglove.md).

Channels, every one JSON with a ``jsonschema`` schema:

- ``/estimate``, ``/compensator``, ``/status``, ``/stats``: the MCAP log's channels, with the log's
  schemas (:mod:`hystbench.formats.mcaplog.schemas`) and the same bytes zenoh sends, so a layout made
  on a log shows the live bench too;
- ``/plot/<channel>`` (``current_A``, ``force_N``, ``flux_Wb``, ``command_V``, ...): each sample
  channel cut into bins of ``round(fs_hz / plot_hz)`` samples, one message per bin (a few hundred
  per second, which the Plot panel follows): the bin's ``mean``, ``min`` and ``max`` (the envelope
  of the waveform) and ``value``, its first sample (an instantaneous value, so that two channels'
  ``value`` pairs lie on the true current-force loop however the excitation aliases against the
  bin rate);
- ``/plot/samples``: those first samples of every channel in one message, for an x-y plot (the
  current-force loop).  The log has no such channels: it keeps every sample in ``/raw``.

Nothing here may hold the pipeline up: the pipeline's listener and block listener only put into a
bounded queue (full: the item is dropped and counted); the decimation (numpy, per block) and the
sending run on this module's own thread.  A failure here is logged and counted (:meth:`health`),
never raised into the pipeline: the service goes on without its live view.

:class:`FoxgloveFleet` is the same view over a fleet (``hystbench router --foxglove``): the
estimates, compensator states, status and stats of every bench a zenoh session reaches, on
``/<bench>/estimate`` etc., with the same schemas.
"""

from __future__ import annotations

import json
import logging
import queue
import re
import threading
import time
from typing import Any, Callable, Mapping

import numpy as np

from ..blocks import SampleBlock
from ..errors import ConfigError
from ..formats.mcaplog.schemas import COMPENSATOR, ESTIMATE, SCHEMAS, STATS, STATUS
from ..messages import json_bytes

__all__ = ["FoxgloveLive", "FoxgloveFleet", "FLEET_MAX_CHANNELS", "serve", "PLOT_PREFIX", "PLOT_SAMPLES",
           "PLOT_POINT_SCHEMA", "plot_samples_schema", "LIVE_TOPICS", "QUEUE_ITEMS", "decimate"]

log = logging.getLogger("hystbench.foxglove")

PLOT_PREFIX = "/plot/"
PLOT_SAMPLES = "/plot/samples"
#: the log's channels that are also served live, with the log's schemas
LIVE_TOPICS = (ESTIMATE, COMPENSATOR, STATUS, STATS)
#: items (raw blocks and messages) waiting for the sending thread; beyond it they are dropped
QUEUE_ITEMS = 256

PLOT_POINT_SCHEMA: dict[str, Any] = {
    "title": "hystbench.PlotPoint",
    "description": "One bin of a sample channel, decimated for plotting: samples [index, index + n)",
    "type": "object",
    "properties": {
        "t_ns": {"type": "integer", "description": "time of the bin's first sample, on the log's clock"},
        "index": {"type": "integer", "description": "sample index of the bin's first sample"},
        "n": {"type": "integer", "description": "samples in the bin"},
        "value": {"type": ["number", "null"], "description": "the bin's first sample (instantaneous)"},
        "mean": {"type": ["number", "null"]},
        "min": {"type": ["number", "null"]},
        "max": {"type": ["number", "null"]},
    },
    "required": ["t_ns", "index", "n", "value", "mean", "min", "max"],
}


def plot_samples_schema(channels: list[str]) -> dict[str, Any]:
    """``/plot/samples``: every channel's instantaneous value at one sample index."""
    props: dict[str, Any] = {"t_ns": {"type": "integer"}, "index": {"type": "integer"}}
    props.update({c: {"type": ["number", "null"]} for c in channels})
    return {"title": "hystbench.PlotSamples", "description": "Every channel at one sample index (the first of "
            "each plot bin): x-y plots such as the current-force loop", "type": "object", "properties": props,
            "required": ["t_ns", "index", *channels]}


def serve(context: Any, name: str, host: str, port: int, *, key: str, fix: str, listener: Any = None) -> Any:
    """foxglove-sdk's server for ``context`` on ``host:port``; one that cannot bind (a taken port) is a
    :class:`ConfigError` of one line: ``<key>: cannot serve Foxglove on HOST:PORT: why; <fix>``."""
    import foxglove

    try:
        return foxglove.start_server(name=name, host=host, port=port, context=context, server_listener=listener)
    except Exception as err:  # the SDK says RuntimeError("FoxgloveError: Failed to bind port: ...")
        why = re.sub(r"\s*\(os error \d+\)", "", str(err).split("Failed to bind port:", 1)[-1]).strip()
        hint = " (another hystbench daemon, or a Foxglove bridge?)" if "in use" in why.lower() else ""
        raise ConfigError(f"{key}: cannot serve Foxglove on {host}:{port}: {why}{hint}; {fix}") from None


def decimate(x: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``x`` (a whole number of bins of ``k`` samples) as per-bin (first, mean, min, max), vectorised."""
    b = x.reshape(-1, k)
    return b[:, 0], b.mean(axis=1, dtype=np.float64), b.min(axis=1), b.max(axis=1)


def _sending_loop(view: Any, send: Callable[[Any], None], what: str) -> None:
    """A view's sending thread: ``send`` each item of its bounded ``_queue`` until ``_stop``.  A
    failure is counted (``errors``, ``last_error``), its traceback logged once per kind, and never
    ends the thread: a view's trouble is its own to report.  Each item is marked done (what a
    replay's drain waits for)."""
    while not view._stop.is_set():
        try:
            item = view._queue.get(timeout=0.2)
        except queue.Empty:
            continue
        try:
            send(item)
        except Exception as err:
            view.errors += 1
            view.last_error = f"{type(err).__name__}: {err}"
            if type(err).__name__ not in view._logged:
                view._logged.add(type(err).__name__)
                log.exception("%s: %s", what, view.last_error)
        finally:
            view._queue.task_done()


def _stop_serving(view: Any, timeout_s: float) -> None:
    """A view's sending thread stopped (within ``timeout_s``), its server stopped (its port free)
    and its channels closed; what fails here has nothing left to free."""
    view._stop.set()
    if view._thread is not None:
        view._thread.join(timeout_s)
    if view._server is not None:
        try:
            view._server.stop()
        except Exception:
            log.exception("stopping the Foxglove server")
        view._server = None
    for ch in view._chan.values():
        try:
            ch.close()
        except Exception:
            pass
    view._chan.clear()


class FoxgloveLive:
    """The Foxglove WebSocket server of one running service and the thread that feeds it.

    ``start()`` binds ``host:port`` (a taken port is a :class:`ConfigError` naming ``[foxglove]
    port``); :meth:`attach` hooks a pipeline (again after each restart: the server and its clients
    stay); :meth:`close` stops the thread and the server, freeing the port."""

    def __init__(self, host: str, port: int, *, name: str, channels: list[str], fs_hz: float,
                 plot_hz: float = 250.0, where: str = "[foxglove]") -> None:
        self.host, self.port, self.name, self.where = host, int(port), name, where
        self.channels = list(channels)
        self.fs_hz = float(fs_hz)
        self.bin = max(1, round(self.fs_hz / float(plot_hz)))
        self._queue: queue.Queue = queue.Queue(QUEUE_ITEMS)
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._server = None
        self._context = None
        self._chan: dict[str, Any] = {}
        self._plot_chans: tuple = ()  # /plot/...: a block is taken only while a client plots one
        self._time_ns: Callable[[int], int] = lambda i: round(i * 1e9 / self.fs_hz)
        self._carry: dict[str, np.ndarray] = {}
        self._carry_index: int | None = None  # sample index of the carried samples' first
        self.sent = 0
        self.dropped_blocks = 0
        self.dropped_messages = 0
        self.errors = 0
        self.last_error = ""
        self._logged: set[str] = set()
        #: set once a client has subscribed to a channel (a replay waits for it before it starts)
        self.subscribed = threading.Event()
        self._listener = _Subscribed(self.subscribed)

    # --- life cycle ------------------------------------------------------------------------------
    def start(self) -> "FoxgloveLive":
        import foxglove

        self._context = foxglove.Context()
        for topic in LIVE_TOPICS:
            self._chan[topic] = foxglove.Channel(topic, schema=SCHEMAS[topic][1],
                                                 context=self._context)
        for c in self.channels:
            self._chan[PLOT_PREFIX + c] = foxglove.Channel(PLOT_PREFIX + c, schema=PLOT_POINT_SCHEMA,
                                                           context=self._context, metadata={"unit_of": c})
        self._chan[PLOT_SAMPLES] = foxglove.Channel(PLOT_SAMPLES, schema=plot_samples_schema(self.channels),
                                                    context=self._context)
        key, fix = ((self.where, f"choose another {self.where}") if self.where.startswith("--")  # an option
                    else (f"{self.where} port", "change [foxglove] port (or host)"))  # the daemon file's table
        self._server = serve(self._context, f"hystbench {self.name}", self.host, self.port, key=key, fix=fix,
                             listener=self._listener)
        self._plot_chans = tuple(ch for t, ch in self._chan.items() if t.startswith(PLOT_PREFIX))
        self.port = self._server.port
        self._thread = threading.Thread(target=self._run, name="foxglove-live", daemon=True)
        self._thread.start()
        log.info("Foxglove live view on %s", self.url)
        return self

    @property
    def url(self) -> str:
        return f"ws://{self.host}:{self.port}"

    def close(self, timeout_s: float = 2.0) -> None:
        _stop_serving(self, timeout_s)

    def wait_for_client(self, timeout_s: float) -> bool:
        """Whether a client subscribed within ``timeout_s``, and what it subscribed to (in that
        subscribe message) is routed to it.  foxglove-sdk 0.30.3 calls the listener's ``on_subscribe``
        before it routes the message's channels to the client, so the event alone would let the
        first messages go to nobody: the channels are then asked (every 10 ms, within the same
        bound) until each subscribed one has its client."""
        deadline = time.monotonic() + timeout_s
        if not self.subscribed.wait(timeout_s):
            return False
        while not all(self._chan[t].has_sinks() for t in self._listener.subscribed_topics() if t in self._chan):
            if time.monotonic() > deadline:
                return False
            self._stop.wait(0.01)
        return True

    def drain(self, timeout_s: float) -> bool:
        """Whether everything queued so far was sent (or failed) within ``timeout_s``."""
        deadline = time.monotonic() + timeout_s
        with self._queue.all_tasks_done:
            while self._queue.unfinished_tasks:
                left = deadline - time.monotonic()
                if left <= 0 or not (self._thread is not None and self._thread.is_alive()):
                    return False
                self._queue.all_tasks_done.wait(min(left, 0.5))
        return True

    def wait_for_clients_to_leave(self, timeout_s: float) -> bool:
        """Whether every subscription was gone (its client unsubscribed or disconnected) within ``timeout_s``."""
        return self._listener.left.wait(timeout_s)

    def attach(self, pipeline: Any) -> None:
        """Feed from ``pipeline``: its messages (a listener) and its raw blocks (a block listener),
        on its clock (the log's: ``index_time_ns``)."""
        self._time_ns = pipeline.index_time_ns
        self._carry, self._carry_index = {}, None
        pipeline.listeners.append(self.on_message)
        pipeline.block_listeners.append(self.on_block)

    def health(self) -> dict[str, Any]:
        return {"url": self.url, "messages_sent": self.sent, "dropped_blocks": self.dropped_blocks,
                "dropped_messages": self.dropped_messages, "errors": self.errors,
                "last_error": self.last_error or None,
                "alive": bool(self._thread is not None and self._thread.is_alive())}

    # --- what the pipeline calls: never blocks -----------------------------------------------------
    def on_message(self, topic: str, obj: Mapping[str, Any]) -> None:
        if topic in self._chan:
            try:
                self._queue.put_nowait((topic, obj))
            except queue.Full:
                self.dropped_messages += 1

    def on_block(self, block: SampleBlock) -> None:
        if not any(ch.has_sinks() for ch in self._plot_chans):
            return  # no client plots: nothing copied (the next block then starts the bins afresh)
        try:  # copied: a source may reuse its buffers once the ring has its samples
            self._queue.put_nowait((None, (block.first_index, {c: np.array(x) for c, x in block.channels.items()})))
        except queue.Full:
            self.dropped_blocks += 1

    # --- the sending thread ----------------------------------------------------------------------
    def _run(self) -> None:
        _sending_loop(self, self._send_item, "Foxglove live view")  # ours to report, never the pipeline's to die of

    def _send_item(self, item: tuple[str | None, Any]) -> None:
        topic, what = item
        if topic is None:
            self._send_block(*what)
        else:
            self._send_message(topic, what)

    def _send_message(self, topic: str, obj: Mapping[str, Any]) -> None:
        ch = self._chan[topic]
        if ch.has_sinks():
            t = obj.get("t_ns")
            ch.log(json_bytes(dict(obj)), log_time=int(t) if isinstance(t, int) else time.time_ns())
            self.sent += 1

    def _send_block(self, first_index: int, data: dict[str, np.ndarray]) -> None:
        k = self.bin
        if self._carry_index is None or self._carry_index + len(next(iter(self._carry.values()), ())) != first_index:
            self._carry, self._carry_index = {}, first_index  # the first block, or after a gap: bins start here
        joined = {c: np.concatenate((self._carry[c], x)) if c in self._carry else x for c, x in data.items()}
        n = len(next(iter(joined.values()), ()))
        whole = n // k * k
        start = self._carry_index
        self._carry = {c: x[whole:] for c, x in joined.items()}
        self._carry_index = start + whole
        if whole == 0:
            return
        index = start + np.arange(0, whole, k, dtype=np.int64)
        t_ns = [self._time_ns(int(i)) for i in index]
        index_list = index.tolist()
        firsts: dict[str, list] = {}
        for c, x in joined.items():
            first, mean, lo, hi = decimate(x[:whole], k)
            firsts[c] = _floats(first)
            ch = self._chan.get(PLOT_PREFIX + c)
            if ch is None or not ch.has_sinks():
                continue
            for i, t, v, m, a, b in zip(index_list, t_ns, firsts[c], _floats(mean), _floats(lo), _floats(hi)):
                ch.log(f'{{"t_ns":{t},"index":{i},"n":{k},"value":{v},"mean":{m},"min":{a},"max":{b}}}'.encode(),
                       log_time=t)
                self.sent += 1
        ch = self._chan[PLOT_SAMPLES]
        if ch.has_sinks():
            names = list(firsts)
            for j, (i, t) in enumerate(zip(index_list, t_ns)):
                body = ",".join(f'"{c}":{firsts[c][j]}' for c in names)
                ch.log(f'{{"t_ns":{t},"index":{i},{body}}}'.encode(), log_time=t)
                self.sent += 1


class _Subscribed:
    """foxglove-sdk's server listener: notes each topic a client subscribes to and sets ``event``;
    sets ``left`` once every subscription is gone again (unsubscribed, or its client disconnected)."""

    def __init__(self, event: threading.Event) -> None:
        self.event = event
        self.left = threading.Event()
        self.topics: set[str] = set()
        self.active = 0
        self._lock = threading.Lock()

    def on_subscribe(self, client: Any, channel: Any) -> None:
        with self._lock:
            self.topics.add(channel.topic)
            self.active += 1
            self.left.clear()
        self.event.set()

    def subscribed_topics(self) -> set[str]:
        with self._lock:
            return set(self.topics)

    def on_unsubscribe(self, client: Any, channel: Any) -> None:
        with self._lock:
            self.active -= 1
            if self.active <= 0:
                self.left.set()


def _floats(x: np.ndarray) -> list[str]:
    """JSON numbers of ``x``; NaN and infinities (which JSON has no numbers for) as ``null``."""
    return [r if r[-1].isdigit() else "null" for r in map(repr, np.asarray(x, dtype=np.float64).tolist())]


# --- one view over a fleet: every bench a zenoh session reaches ---------------------------------------
#: channels one fleet view creates at most (a publisher inventing bench names cannot grow it further)
FLEET_MAX_CHANNELS = 1024


class FoxgloveFleet:
    """One Foxglove WebSocket server showing every bench a zenoh session reaches: the router's
    (``hystbench router --foxglove``, docs/fleet.md), so a lab opens one connection for all benches.

    It subscribes to what the daemons already publish, ``hystbench/*/estimate``, ``compensator``,
    ``status`` and ``stats``, and re-publishes each payload unchanged on ``/<bench>/estimate`` etc.,
    with the log's schemas (the per-daemon view's :data:`LIVE_TOPICS`).  A bench's channel is created
    when its first message arrives, so benches that join later appear then.  No ``/plot`` channels:
    they are cut from raw blocks (megabytes per second per bench), which the router is not made to
    carry for a view; each daemon's own ``[foxglove]`` view has them.

    zenoh's callback only puts into a bounded queue (full: dropped and counted); channels are created
    and messages sent on this view's own thread.  A payload that is not a JSON object is not
    forwarded (counted as ``rejected``)."""

    def __init__(self, host: str, port: int, *, where: str = "--foxglove", queue_items: int = 4 * QUEUE_ITEMS,
                 max_channels: int = FLEET_MAX_CHANNELS) -> None:
        self.host, self.port, self.where = host, int(port), where
        self.max_channels = max_channels
        self._queue: queue.Queue = queue.Queue(queue_items)
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._server = None
        self._context = None
        self._subs: list = []
        self._chan: dict[str, Any] = {}
        self.benches: set[str] = set()
        self.sent = self.dropped = self.rejected = self.errors = 0
        self.last_error = ""
        self._logged: set[str] = set()

    def start(self, session: Any) -> "FoxgloveFleet":
        """Serve on ``host:port`` (taken: a :class:`ConfigError` naming ``where``), then subscribe on
        ``session``."""
        import foxglove

        from ..acquisition.zenoh_bus import PREFIX

        self._context = foxglove.Context()
        self._server = serve(self._context, "hystbench fleet", self.host, self.port, key=self.where,
                             fix=f"choose another {self.where}")
        self.port = self._server.port
        self._thread = threading.Thread(target=self._run, name="foxglove-fleet", daemon=True)
        self._thread.start()
        try:
            self._subs = [session.declare_subscriber(f"{PREFIX}/*{topic}", self._on_sample) for topic in LIVE_TOPICS]
        except Exception:
            self.close()
            raise
        log.info("Foxglove view of the fleet on %s", self.url)
        return self

    @property
    def url(self) -> str:
        return f"ws://{self.host}:{self.port}"

    def close(self, timeout_s: float = 2.0) -> None:
        for sub in self._subs:
            try:
                sub.undeclare()
            except Exception:  # the session closed first: nothing left to undeclare
                pass
        self._subs = []
        _stop_serving(self, timeout_s)

    def health(self) -> dict[str, Any]:
        return {"url": self.url, "benches": sorted(self.benches), "channels": len(self._chan),
                "messages_sent": self.sent, "dropped": self.dropped, "rejected": self.rejected,
                "errors": self.errors, "last_error": self.last_error or None,
                "alive": bool(self._thread is not None and self._thread.is_alive())}

    # --- zenoh's callback: never blocks ----------------------------------------------------------------
    def _on_sample(self, sample: Any) -> None:
        self.take(str(sample.key_expr), sample.payload.to_bytes())

    def take(self, key: str, payload: bytes) -> None:
        """Queue ``payload`` published on ``key`` (``hystbench/<bench>/<topic>``) for sending."""
        try:
            self._queue.put_nowait((key, payload))
        except queue.Full:
            self.dropped += 1

    # --- the sending thread ----------------------------------------------------------------------------
    def _run(self) -> None:
        _sending_loop(self, lambda item: self._send(*item), "Foxglove fleet view")  # the router goes on routing

    def _send(self, key: str, payload: bytes) -> None:
        import foxglove

        _, bench, name = key.split("/", 2)
        topic = f"/{bench}/{name}"
        try:
            obj = json.loads(payload)
        except ValueError:
            obj = None
        if not isinstance(obj, dict):
            self.rejected += 1
            return
        ch = self._chan.get(topic)
        if ch is None:
            if len(self._chan) >= self.max_channels:
                self.rejected += 1
                return
            ch = self._chan[topic] = foxglove.Channel(topic, schema=SCHEMAS["/" + name][1], context=self._context)
            self.benches.add(bench)
        if ch.has_sinks():
            t = obj.get("t_ns")
            ch.log(payload, log_time=t if isinstance(t, int) and t >= 0 else time.time_ns())
            self.sent += 1
