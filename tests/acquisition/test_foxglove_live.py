"""The daemon's live view in Foxglove, as a Foxglove client sees it: a real daemon (simulated rig,
sweeping) and a WebSocket client that is not ours (the ``websockets`` package speaking the
documented protocol, subprotocol ``foxglove.sdk.v1``: JSON ``serverInfo`` and ``advertise``, a
JSON ``subscribe``, binary message data ``op 0x01 | u32 subscription id | u64 log time | payload``).
Also: disabled, nothing listens; a taken port is refused naming ``[foxglove] port``; the bridge
drops (counted) rather than blocks, and its own failure never stops the service.
Every wait is bounded by a timeout; nothing sleeps."""

from __future__ import annotations

import json
import os
import socket
import struct
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import pytest
from websockets.sync.client import connect

from hystbench.acquisition.zenoh_bus import free_port
from hystbench.blocks import SampleBlock
from hystbench.deadline import Deadline
from hystbench.formats.mcaplog.schemas import SCHEMAS
from hystbench.service.foxglove_live import PLOT_POINT_SCHEMA, QUEUE_ITEMS, FoxgloveLive, decimate

from .conftest import HANG_S, ROOT, Daemon

pytestmark = pytest.mark.slow(15)  # ~15 s: handed to a worker before lighter files (tests/conftest.py)

SUBPROTOCOL = "foxglove.sdk.v1"
UNKNOWN_CHANNEL = "Unknown channel ID: "  #: the server's status when a subscribe names a channel it does not know
FS = 100_000.0


def write_config(path: Path, zport: int, fport: int, logs: Path, *, enabled: bool = True) -> None:
    path.write_text(f'[daemon]\nbench = "fx"\nlog_dir = "{logs.as_posix()}"\nstats_interval_s = 0.5\n'
                    '[source]\nkind = "sim"\n[recording]\nenabled = false\n'
                    f'[zenoh]\nlisten = ["tcp/127.0.0.1:{zport}"]\n'
                    f'[foxglove]\nenabled = {str(enabled).lower()}\nhost = "127.0.0.1"\nport = {fport}\n'
                    '[sweep]\nfrequencies_hz = [320.0]\ndwell_s = 60.0\nautostart = true\n', encoding="utf-8")


class Client:
    """A Foxglove WebSocket client: the documented protocol over the ``websockets`` package."""

    def __init__(self, ws) -> None:
        self.ws = ws
        self.channels: dict[str, dict] = {}
        self.topic_of: dict[int, str] = {}
        self.resubscribed = 0

    def advertised(self, deadline: Deadline, topics: tuple[str, ...] = ()) -> dict[str, dict]:
        """Read until the server has advertised channels (and, if given, all of ``topics``: a server
        advertises a channel made later when it is made)."""
        while not self.channels or not set(topics) <= set(self.channels):
            if deadline.expired:
                raise AssertionError(f"no advertise of {sorted(set(topics) - set(self.channels))}; "
                                     f"advertised: {sorted(self.channels)}")
            try:
                msg = self.ws.recv(timeout=max(0.01, deadline.left(1.0)))
            except TimeoutError:
                continue
            if isinstance(msg, str):
                self.on_text(json.loads(msg))
        return self.channels

    def on_text(self, j: dict) -> None:
        if j["op"] == "advertise":
            self.channels.update({c["topic"]: c for c in j["channels"]})
        elif j["op"] == "unadvertise":
            self.channels = {t: c for t, c in self.channels.items() if c["id"] not in j["channelIds"]}
        elif j["op"] == "status" and str(j.get("message", "")).startswith(UNKNOWN_CHANNEL):
            # foxglove-sdk 0.30.3 may refuse a subscribe that follows at once the advertise of a channel
            # made while this client was connected (measured: the fleet view's channels; docs/fleet.md):
            # subscribed again, as the race is over once the refusal came back
            cid = int(j["message"][len(UNKNOWN_CHANNEL):])
            self.resubscribed += 1
            assert self.resubscribed <= 100, "subscribe refused 100 times"
            self.ws.send(json.dumps({"op": "subscribe", "subscriptions": [
                {"id": k, "channelId": cid} for k, t in self.topic_of.items() if self.channels[t]["id"] == cid]}))

    def subscribe(self, *topics: str) -> None:
        subs = []
        for k, t in enumerate(topics, start=len(self.topic_of) + 1):
            self.topic_of[k] = t
            subs.append({"id": k, "channelId": self.channels[t]["id"]})
        self.ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))

    def messages(self, deadline: Deadline):
        """(topic, log time ns, decoded JSON) of each message data frame until the deadline."""
        while not deadline.expired:
            try:
                msg = self.ws.recv(timeout=max(0.01, deadline.left(1.0)))
            except TimeoutError:
                continue
            if isinstance(msg, bytes) and msg[0] == 0x01:
                sub, t_ns = struct.unpack_from("<IQ", msg, 1)
                yield self.topic_of[sub], t_ns, json.loads(msg[13:])
            elif isinstance(msg, str):  # channels advertised meanwhile
                self.on_text(json.loads(msg))


def _check(obj: dict, schema: dict) -> None:
    """``obj`` has the schema's required fields, each of the type the schema gives."""
    types = {"integer": (int,), "number": (int, float), "string": (str,), "object": (dict,), "array": (list,),
             "boolean": (bool,), "null": (type(None),)}
    assert set(schema.get("required", ())) <= set(obj), (set(schema["required"]) - set(obj), obj)
    for k, spec in schema.get("properties", {}).items():
        if k in obj and "type" in spec:
            allowed = spec["type"] if isinstance(spec["type"], list) else [spec["type"]]
            assert isinstance(obj[k], tuple(t for a in allowed for t in types[a])), (k, obj[k], spec)


def test_a_foxglove_client_gets_the_plot_channels_and_the_estimates_live(tmp_path: Path) -> None:
    zport, fport, cfg = free_port(), free_port(), tmp_path / "daemon.toml"
    write_config(cfg, zport, fport, tmp_path / "logs")
    d = Daemon(tmp_path, cfg)
    try:
        d.wait_for("READY=1")
        with connect(f"ws://127.0.0.1:{fport}", subprotocols=[SUBPROTOCOL], open_timeout=HANG_S,
                     max_size=None) as ws:
            points, estimates = _receive(Client(ws))
    finally:
        d.close()
    _check_received(points, estimates)


def _receive(client: Client) -> tuple[list, list]:
    """What a client subscribed to the current's plot channel and the estimates receives, until it
    has 500 points and 3 estimates with delays."""
    assert client.ws.subprotocol == SUBPROTOCOL
    channels = client.advertised(Deadline(HANG_S))
    assert {"/estimate", "/compensator", "/status", "/stats", "/plot/samples", "/plot/current_A", "/plot/force_N",
            "/plot/flux_Wb", "/plot/command_V"} <= set(channels), sorted(channels)
    for topic in ("/estimate", "/compensator", "/status", "/stats"):  # the log's schemas, byte for byte in JSON
        name, schema = SCHEMAS[topic]
        c = channels[topic]
        assert (c["encoding"], c["schemaEncoding"], c["schemaName"]) == ("json", "jsonschema", name)
        assert json.loads(c["schema"]) == schema
    assert json.loads(channels["/plot/current_A"]["schema"]) == PLOT_POINT_SCHEMA
    client.subscribe("/plot/current_A", "/estimate")
    points, estimates = [], []
    deadline = Deadline(HANG_S)
    for topic, t_ns, obj in client.messages(deadline):
        (points if topic == "/plot/current_A" else estimates).append((t_ns, obj))
        if len([e for _, e in estimates if e["delays_s"]]) >= 3 and len(points) >= 500:
            break
    else:
        raise AssertionError(f"{len(points)} plot points and {len(estimates)} estimates in {HANG_S:g} s")
    return points, estimates


def _check_received(points: list, estimates: list) -> None:
    for t_ns, obj in points:
        _check(obj, PLOT_POINT_SCHEMA)
        assert t_ns == obj["t_ns"] and obj["min"] <= obj["value"] <= obj["max"]
    index = np.array([o["index"] for _, o in points])
    bins = {o["n"] for _, o in points}
    assert bins == {400}, bins  # 250 points per second at 100 kHz
    steps = np.diff(index)
    assert (steps > 0).all() and np.median(steps) == 400  # consecutive bins (a gap only if the queue dropped)
    rate_sample_clock = FS * (len(points) - 1) / (index[-1] - index[0])
    # and on the messages' log times (the log's clock, a function of the sample index: no wall time here)
    rate_log_time = 1e9 * (len(points) - 1) / (points[-1][0] - points[0][0])
    assert 200 <= rate_sample_clock <= 300 and 200 <= rate_log_time <= 300, (rate_sample_clock, rate_log_time)
    amplitude = max(o["max"] for _, o in points) - min(o["min"] for _, o in points)
    assert amplitude == pytest.approx(1.4, rel=0.1)  # the envelope keeps the 1.4 A-pp the bin means average out
    est_schema = SCHEMAS["/estimate"][1]
    good = [e for _, e in estimates if e["delays_s"]]
    for _, e in estimates:
        _check(e, est_schema)
    for e in good:
        assert set(e["delays_s"]) == set(e["delays_std_s"]) == {"hysteresis", "instrument", "total"}
        assert 0 < e["delays_s"]["hysteresis"] < 1e-3 and 0 < e["delays_std_s"]["hysteresis"] < 1e-5
        assert e["nominal_frequency_hz"] == 320.0


def _listening(port: int) -> bool:
    with socket.socket() as s:
        s.settimeout(5.0)
        return s.connect_ex(("127.0.0.1", port)) == 0


def test_disabled_nothing_listens(tmp_path: Path) -> None:
    zport, fport, cfg = free_port(), free_port(), tmp_path / "daemon.toml"
    write_config(cfg, zport, fport, tmp_path / "logs", enabled=False)
    d = Daemon(tmp_path, cfg)
    try:
        d.wait_for("READY=1")
        assert d.proc.poll() is None
        assert not _listening(fport)
    finally:
        d.close()
    assert "Foxglove" not in d.stderr()


def test_a_taken_port_is_refused_naming_the_key(tmp_path: Path) -> None:
    zport, cfg = free_port(), tmp_path / "daemon.toml"
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        fport = taken.getsockname()[1]
        write_config(cfg, zport, fport, tmp_path / "logs")
        env = dict(os.environ, STATE_DIRECTORY=str(tmp_path / "state"))
        run = subprocess.run([sys.executable, "-m", "hystbench", "daemon", "--config", str(cfg)], cwd=ROOT, env=env,
                             capture_output=True, text=True, timeout=HANG_S)
    assert run.returncode == 2, run.stderr[-2000:]
    assert run.stderr.strip().splitlines()[-1] == (
        f"hystbench daemon: error: {cfg} [foxglove] port: cannot serve Foxglove on 127.0.0.1:{fport}: Address "
        "already in use (another hystbench daemon, or a Foxglove bridge?); change [foxglove] port (or host)")


# --- the bridge in the process: it never holds the pipeline up, and its failure is its own ------------

def _block(first: int, n: int) -> SampleBlock:
    i = np.arange(first, first + n)
    return SampleBlock(first, FS, {"current_A": np.sin(i / 50.0).astype(np.float32),
                                   "force_N": (i % 7).astype(np.float32)})


class _Pipeline:
    def __init__(self) -> None:
        self.listeners, self.block_listeners = [], []

    @staticmethod
    def index_time_ns(index: int) -> int:
        return round(index * 1e9 / FS)


def test_decimate_is_bin_first_mean_min_max() -> None:
    x = np.arange(12, dtype=np.float32)
    first, mean, lo, hi = decimate(x, 4)
    assert first.tolist() == [0, 4, 8] and mean.tolist() == [1.5, 5.5, 9.5]
    assert lo.tolist() == [0, 4, 8] and hi.tolist() == [3, 7, 11]


def test_the_bridge_drops_what_it_cannot_take_and_survives_its_own_failure() -> None:
    live = FoxgloveLive("127.0.0.1", free_port(), name="t", channels=["current_A", "force_N"], fs_hz=FS)
    p = _Pipeline()
    live.attach(p)
    p.block_listeners[0](_block(0, 1000))  # no client plots: not even taken
    assert live._queue.qsize() == 0 and live.dropped_blocks == 0
    live.start()
    try:
        with connect(f"ws://127.0.0.1:{live.port}", subprotocols=[SUBPROTOCOL], open_timeout=HANG_S) as ws:
            client = Client(ws)
            client.advertised(Deadline(HANG_S))
            client.subscribe("/plot/current_A")
            deadline, first = Deadline(HANG_S), None
            k = 0
            while first is None and not deadline.expired:  # blocks until the subscription shows
                p.block_listeners[0](_block(k * 1000, 1000))
                k += 1
                first = next(client.messages(Deadline(0.05)), None)
            assert first is not None and first[0] == "/plot/current_A"

            taken, release = threading.Event(), threading.Event()

            def stuck(*args):  # a sending thread held up: the pipeline's side must not wait for it
                taken.set()
                release.wait(HANG_S)
                raise RuntimeError("the view broke")

            live._send_block = stuck
            while not taken.is_set() and not deadline.expired:
                p.block_listeners[0](_block(k * 1000, 1000))
                k += 1
                taken.wait(0.05)
            assert taken.is_set()
            dropped, queued = live.dropped_blocks, live._queue.qsize()
            for _ in range(QUEUE_ITEMS - queued + 10):
                p.block_listeners[0](_block(k * 1000, 1000))
                k += 1
            assert live.dropped_blocks - dropped == 10  # full: dropped and counted, never waited for
            release.set()  # now every block fails: counted and logged, the thread goes on
            while live._queue.qsize() and not deadline.expired:
                taken.clear()
                taken.wait(1.0)
            assert live.errors >= QUEUE_ITEMS and live.health()["alive"]
            assert live.health()["last_error"] == "RuntimeError: the view broke"
    finally:
        live.close()
    assert not live.health()["alive"]
