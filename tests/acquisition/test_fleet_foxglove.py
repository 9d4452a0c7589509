"""One Foxglove view of a fleet (issue 31): a real zenoh router with the fleet view on its session,
two real daemons (subprocesses, simulated rig, sweeping) that are the router's clients, and a
WebSocket client that is not ours (``websockets`` speaking ``foxglove.sdk.v1``): it sees the channels
of both benches, with the log's schemas, and receives estimates from both.  A bench that appears
later gets its channels on its first message; a payload that is no JSON object is not forwarded; a
full queue drops and counts; a taken port is refused naming ``--foxglove``.
Every wait ends on its event; HANG_S only turns a hang into a failure."""

from __future__ import annotations

import json
import socket
import subprocess
import sys
import threading
from pathlib import Path

from websockets.sync.client import connect

from hystbench.acquisition.zenoh_bus import free_port, load_zenoh_config, open_session
from hystbench.deadline import Deadline
from hystbench.formats.mcaplog.schemas import SCHEMAS
from hystbench.service.foxglove_live import FoxgloveFleet
from hystbench.service.router import Router

from .conftest import HANG_S, ROOT, Daemon
from .test_fleet import daemon_file, run
from .test_foxglove_live import SUBPROTOCOL, Client, _check

TOPICS = ("estimate", "compensator", "status", "stats")


def test_one_foxglove_view_shows_every_bench_through_the_router(tmp_path: Path) -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    with Router([endpoint]) as router:
        view = FoxgloveFleet("127.0.0.1", free_port()).start(router.session)
        daemons = [Daemon(tmp_path, daemon_file(tmp_path / f"{b}.toml", b, endpoint, tmp_path / "logs"), name=b)
                   for b in ("f1", "f2")]
        try:
            for d in daemons:
                d.wait_for("READY=1")
            with connect(view.url, subprotocols=[SUBPROTOCOL], open_timeout=HANG_S, max_size=None) as ws:
                client = Client(ws)
                assert ws.subprotocol == SUBPROTOCOL
                wanted = ("/f1/estimate", "/f2/estimate", "/f1/status", "/f2/status")
                channels = client.advertised(Deadline(HANG_S), wanted)
                for topic in channels:  # the log's schemas, as the per-daemon view has them
                    name, schema = SCHEMAS["/" + topic.rsplit("/", 1)[1]]
                    c = channels[topic]
                    assert (c["encoding"], c["schemaEncoding"], c["schemaName"]) == ("json", "jsonschema", name)
                    assert json.loads(c["schema"]) == schema
                    assert topic.split("/")[1] in ("f1", "f2") and topic.rsplit("/", 1)[1] in TOPICS, topic
                client.subscribe("/f1/estimate", "/f2/estimate")
                got: dict[str, list] = {"/f1/estimate": [], "/f2/estimate": []}
                for topic, t_ns, obj in client.messages(Deadline(HANG_S)):
                    got[topic].append(obj)
                    assert t_ns == obj["t_ns"]
                    if all(len([e for e in es if e["delays_s"]]) >= 2 for es in got.values()):
                        break
                else:
                    raise AssertionError({t: len(es) for t, es in got.items()})
            for es in got.values():
                for e in es:
                    _check(e, SCHEMAS["/estimate"][1])
                    assert e["nominal_frequency_hz"] == 320.0
                assert 0 < [e for e in es if e["delays_s"]][-1]["delays_s"]["hysteresis"] < 1e-3
            health = view.health()
            assert {"f1", "f2"} <= set(health["benches"]) and health["alive"]
            assert health["messages_sent"] >= 4 and health["errors"] == 0, health
        finally:
            for d in daemons:
                d.close()
            view.close()


def test_a_bench_that_appears_later_gets_its_channels_and_garbage_is_not_forwarded() -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    with Router([endpoint]) as router:
        view = FoxgloveFleet("127.0.0.1", free_port()).start(router.session)
        late = open_session(load_zenoh_config(None, connect=[endpoint]))
        try:
            with connect(view.url, subprotocols=[SUBPROTOCOL], open_timeout=HANG_S) as ws:
                client = Client(ws)
                _serverinfo = ws.recv(timeout=HANG_S)
                assert client.channels == {}  # no bench yet, no channel
                status = {"t_ns": 123, "level": "info", "event": "started", "message": "late bench"}
                payload = json.dumps(status).encode()
                deadline = Deadline(HANG_S)
                while "/late/status" not in client.channels:  # until the router's subscriber is known here
                    late.put("hystbench/late/status", payload)
                    try:
                        client.advertised(Deadline(min(1.0, deadline.left())), ("/late/status",))
                    except AssertionError:
                        assert not deadline.expired, "no /late/status advertised"
                # not forwarded: no channel /rogue/status (zenoh delivers in order: seen before /late2)
                late.put("hystbench/rogue/status", b"not json")
                while "/late2/status" not in client.channels:
                    late.put("hystbench/late2/status", payload)
                    try:
                        client.advertised(Deadline(min(1.0, deadline.left())), ("/late2/status",))
                    except AssertionError:
                        assert not deadline.expired, "no /late2/status advertised"
                assert set(client.channels) == {"/late/status", "/late2/status"} and view.rejected == 1
                client.subscribe("/late/status")
                first = None
                while first is None and not deadline.expired:  # until the subscription shows
                    late.put("hystbench/late/status", payload)
                    first = next(client.messages(Deadline(min(0.5, deadline.left()))), None)
                assert first == ("/late/status", 123, status)
        finally:
            late.close()
            view.close()


def test_the_fleet_view_drops_what_it_cannot_take_and_survives_its_failure() -> None:
    with Router([f"tcp/127.0.0.1:{free_port()}"]) as router:
        view = FoxgloveFleet("127.0.0.1", free_port(), queue_items=8).start(router.session)
        try:
            taken, release = threading.Event(), threading.Event()

            def stuck(*args):  # a sending thread held up: zenoh's callback must not wait for it
                taken.set()
                release.wait(HANG_S)
                raise RuntimeError("the view broke")

            view._send = stuck
            view.take("hystbench/x/status", b"{}")
            assert taken.wait(HANG_S)
            for _ in range(8 + 10):
                view.take("hystbench/x/status", b"{}")
            assert view.dropped == 10  # full: dropped and counted, never waited for
            release.set()
            deadline = Deadline(HANG_S)
            while view.errors < 9 and not deadline.expired:  # every queued one fails: counted, the thread goes on
                taken.clear()
                taken.wait(1.0)
            assert view.errors == 9 and view.health()["alive"]
            assert view.health()["last_error"] == "RuntimeError: the view broke"
        finally:
            view.close()
    assert not view.health()["alive"]


def test_a_taken_foxglove_port_is_refused_naming_the_option(capsys) -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        code, out, err = run(["router", "--listen", endpoint, "--foxglove", str(port)], capsys)
    assert code == 2 and out == ""
    assert err == (f"hystbench router: error: --foxglove: cannot serve Foxglove on 127.0.0.1:{port}: Address "
                   "already in use (another hystbench daemon, or a Foxglove bridge?); choose another --foxglove\n")
    with Router([endpoint]):  # the router it had opened was closed again: its port is free
        pass
    code, out, err = run(["router", "--foxglove", "localhost:http"], capsys)
    assert code == 2 and "--foxglove: 'localhost:http' is not [HOST:]PORT" in err.splitlines()[-1], err


def test_the_router_says_where_its_foxglove_view_is(tmp_path: Path) -> None:
    endpoint, port = f"tcp/127.0.0.1:{free_port()}", free_port()
    proc = subprocess.Popen([sys.executable, "-m", "hystbench", "router", "--listen", endpoint,
                             "--foxglove", f"127.0.0.1:{port}"], cwd=ROOT,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert f"listening on {endpoint}" in proc.stdout.readline()
        line = proc.stdout.readline()
        assert line.strip() == f"hystbench router: Foxglove view of every bench on ws://127.0.0.1:{port}", \
            (line, proc.stderr.read() if proc.poll() is not None else "")
        with connect(f"ws://127.0.0.1:{port}", subprotocols=[SUBPROTOCOL], open_timeout=HANG_S) as ws:
            info = json.loads(ws.recv(timeout=HANG_S))
            assert info["op"] == "serverInfo" and info["name"] == "hystbench fleet"
        proc.terminate()
        assert proc.wait(timeout=HANG_S) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
