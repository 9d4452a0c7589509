"""``hystbench replay LOG --foxglove PORT``: a log replayed on the daemon's live view (issue 31), so a
layout made live shows a replay: a real ``hystbench replay`` process and a WebSocket client that is
not ours (``websockets`` speaking ``foxglove.sdk.v1``).  The replay waits for the client's
subscription, then the client gets every bin of the log on ``/plot/current_A`` (none dropped: the
replay starts only once it is subscribed) and every estimate of the replay on ``/estimate``, on the
log's clock, then ``replay_finished`` on ``/status``; the replay is served until the client leaves.
A taken port is refused naming ``--foxglove``.  Every wait ends on its event; HANG_S only
turns a hang into a failure."""

from __future__ import annotations

import json
import socket
import subprocess
import sys
from pathlib import Path

import numpy as np
from websockets.sync.client import connect

from hystbench.acquisition.zenoh_bus import free_port
from hystbench.blocks import SampleBlock
from hystbench.deadline import Deadline
from hystbench.formats.mcaplog import McapRecorder
from hystbench.formats.mcaplog.schemas import SCHEMAS
from hystbench.messages import OperatingPoint
from hystbench.service.foxglove_live import PLOT_POINT_SCHEMA

from .conftest import HANG_S, ROOT
from .test_fleet import run
from .test_foxglove_live import SUBPROTOCOL, Client, _check

FS = 10_000.0
BLOCKS, N = 20, 1000
BIN = 40  # round(FS / plot_hz), plot_hz 250


def sine_log(path: Path) -> Path:
    """Two seconds at 320 Hz: current, flux and force, each later than the one before."""
    w = 2 * np.pi * 320.0
    with McapRecorder(path, compression="none", idle_raw="full",
                      metadata={"recording": {"rig": "ecore_pm", "frequency_Hz": 320.0, "sample_rate_Hz": FS,
                                              "current_pp_A": 1.4}}) as rec:
        for k in range(BLOCKS):
            t = (N * k + np.arange(N)) / FS
            rec.add_block(SampleBlock(N * k, FS, {"current_A": 0.7 * np.sin(w * t),
                                                  "flux_Wb": 1e-4 * np.sin(w * t - 0.05),
                                                  "force_N": 20 * np.sin(w * t - 0.1)},
                                      meta=OperatingPoint(320.0, 1.4).to_meta()))
    return path


def test_a_replay_on_foxglove_gives_the_live_channels(tmp_path: Path) -> None:
    log, port = sine_log(tmp_path / "sine.mcap"), free_port()
    proc = subprocess.Popen([sys.executable, "-m", "hystbench", "replay", str(log), "--speed", "max",
                             "--foxglove", str(port)], cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)
    try:
        line = proc.stdout.readline()  # printed once it serves
        assert f"Foxglove view on ws://127.0.0.1:{port}" in line, (line, proc.stderr.read() if proc.poll() else "")
        points, estimates = [], []
        with connect(f"ws://127.0.0.1:{port}", subprotocols=[SUBPROTOCOL], open_timeout=HANG_S, max_size=None) as ws:
            client = Client(ws)
            channels = client.advertised(Deadline(HANG_S), ("/plot/current_A", "/plot/samples", "/estimate"))
            assert {"/plot/current_A", "/plot/force_N", "/plot/flux_Wb", "/plot/samples", "/estimate", "/status",
                    "/stats", "/compensator"} <= set(channels)
            assert json.loads(channels["/plot/current_A"]["schema"]) == PLOT_POINT_SCHEMA
            assert json.loads(channels["/estimate"]["schema"]) == SCHEMAS["/estimate"][1]
            client.subscribe("/plot/current_A", "/estimate", "/status")
            finished = None
            for topic, t_ns, obj in client.messages(Deadline(HANG_S)):  # until the replay says it has finished
                if topic == "/status":
                    if obj["event"] == "replay_finished":
                        finished = obj
                        break
                else:
                    (points if topic == "/plot/current_A" else estimates).append((t_ns, obj))
            assert finished is not None, (len(points), len(estimates))
            assert proc.poll() is None  # served until this client leaves
        assert proc.wait(timeout=HANG_S) == 0, proc.stderr.read()
        out = proc.stdout.read()
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert [o["index"] for _, o in points] == list(range(0, BLOCKS * N, BIN))  # every bin, in order
    for t_ns, o in points:
        _check(o, PLOT_POINT_SCHEMA)
        assert t_ns == o["t_ns"] and o["n"] == BIN and o["min"] <= o["value"] <= o["max"]
    assert out.strip().splitlines()[-1] == f"{finished['estimates']} estimates (0 refused) from {log}"
    assert finished["estimates"] > 0 and len(estimates) == finished["estimates"]  # every one, none dropped
    for t_ns, e in estimates:
        _check(e, SCHEMAS["/estimate"][1])
        assert t_ns == e["t_ns"] and e["nominal_frequency_hz"] == 320.0


def test_a_taken_port_is_refused_naming_foxglove(tmp_path: Path, capsys) -> None:
    log = sine_log(tmp_path / "sine.mcap")
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        code, out, err = run(["replay", str(log), "--foxglove", str(port)], capsys)
    assert code == 2 and out == ""
    assert err == (f"hystbench replay: error: --foxglove: cannot serve Foxglove on 127.0.0.1:{port}: Address "
                   "already in use (another hystbench daemon, or a Foxglove bridge?); choose another --foxglove\n")
    code, out, err = run(["replay", str(log), "--foxglove", "1", "--out", str(tmp_path / "o.mcap")], capsys)
    assert code == 2 and err.splitlines() == ["hystbench replay: error: --out: not with --foxglove (record the "
                                              "replay without a view, or view it unrecorded)"], err
