"""The bench on zenoh: payload codec, key space, queryables and commands, the shipped access
control (a denied subject cannot start a sweep), and ``hystbench watch`` from another process.
Every session listens on an ephemeral port of 127.0.0.1 (never 7447); every wait is bounded."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import threading
from pathlib import Path
from typing import Callable

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hystbench.acquisition.zenoh_bus import (Subscription, ZenohBus, free_port, key, load_zenoh_config, open_session,
                                             peer_config, query_json, send_command)
from hystbench.blocks import BlockFlags, SampleBlock
from hystbench.config import CONFIG_DIR
from hystbench.deadline import Deadline
from hystbench.errors import BenchError, CommandRefused, ConfigError, NetworkError, NoReply
from hystbench.formats.mcaplog import RAW, iter_blocks
from hystbench.formats.mcaplog.schemas import SCHEMAS, schema_bytes
from hystbench.formats.raw_block import decode, encode_binary
from hystbench.messages import Estimate, OperatingPoint
from hystbench.service.daemon_config import load_daemon_config
from hystbench.service.service import BenchService

ROOT = Path(__file__).resolve().parents[2]
HANG_S = 60.0  # a safety timeout: waits end on their event, only a hang takes this long


def answered(session, key_expr: str) -> list:
    """The replies to a query, asked until the service answers: a client that has just connected
    may not see the service's queryables yet (discovery takes what a busy machine gives it)."""
    deadline = Deadline(HANG_S)
    while not deadline.expired:
        got = query_json(session, key_expr, timeout_s=1.0)
        if got:
            return got
    raise AssertionError(f"no reply from {key_expr} within {HANG_S} s")


def seen(sub: Subscription, event: str) -> bool:
    """Whether status event ``event`` comes (read until it does; the timeout turns a hang into False)."""
    return event in (json.loads(p)["event"] for _, p, _ in sub.iter(seconds=HANG_S))


@settings(max_examples=50, deadline=None)
@given(n=st.integers(0, 200), dtype=st.sampled_from([np.float32, np.float64]), first=st.integers(-10**9, 10**12),
       flags=st.sampled_from(list(BlockFlags)), gap=st.integers(0, 10**6))
def test_raw_payload_round_trip(n, dtype, first, flags, gap) -> None:
    rng = np.random.default_rng(n)
    blk = SampleBlock(first, 100_000.0, {"current_A": rng.standard_normal(n).astype(dtype),
                                         "flux_Wb": rng.standard_normal(n).astype(dtype)}, flags=flags, gap_samples=gap)
    payload = encode_binary(blk, ["flux_Wb"])
    (h,) = np.frombuffer(payload[:4], "<u4")  # the documented layout, read by hand
    head = json.loads(payload[4:4 + h])
    assert head["channels"] == [{"name": "flux_Wb", "unit": "Wb", "dtype": np.dtype(dtype).name}]
    assert len(payload) == 4 + h + n * np.dtype(dtype).itemsize
    back = decode(payload)
    assert (back.first_index, back.flags, back.gap_samples, list(back.channels)) == (first, flags, gap, ["flux_Wb"])
    assert back.channels["flux_Wb"].tobytes() == blk.channels["flux_Wb"].tobytes()


def test_key_space_and_bad_payloads() -> None:
    assert key("bench1", "raw", "force_N") == "hystbench/bench1/raw/force_N"
    for bad in ("", "a/b", "x*", "q?"):
        with pytest.raises(ConfigError, match="bench name"):
            key(bad)
    with pytest.raises(BenchError, match="hystbench/t/raw: not a hystbench.RawBlock"):
        decode(b"\x05\x00\x00\x00{}", "hystbench/t/raw")


def test_a_remote_subscriber_sees_the_operating_point_and_the_bytes_decode_through_the_mcap_path(tmp_path) -> None:
    """A raw block published on zenoh reaches a subscriber in another session over TCP on
    loopback with its meta (operating point, settling, waveform table) as published; and the very
    payload it received, put in an MCAP log as a /raw message, reads back through the log reader
    as the same block (one codec: before, zenoh dropped the meta and its bytes were no RawBlock)."""
    port = free_port()
    bus = ZenohBus("t", load_zenoh_config(None, listen=[f"tcp/127.0.0.1:{port}"])).open()
    s = client(port)
    sub = Subscription(s, key("t", "raw"))
    point = OperatingPoint(320.0, 1.4, offset_a=0.1, output_on=True, settling=True, table=3)
    rng = np.random.default_rng(5)
    blk = SampleBlock(123_456, 100_000.0, {"current_A": rng.standard_normal(500).astype(np.float32),
                                           "force_N": rng.standard_normal(500)},
                      flags=BlockFlags.GAP, gap_samples=17, meta=point.to_meta())
    try:
        got, deadline = None, Deadline(HANG_S)  # a safety timeout: the loop ends on the delivery
        while got is None and not deadline.expired:  # discovery: put until the subscriber has one
            bus.publish_block(blk)
            got = sub.get(0.5)
        assert got is not None, "no raw block reached the subscriber"
    finally:
        sub.close()
        s.close()
        bus.close()
    keyexpr, payload, _ = got
    back = decode(payload, keyexpr)
    assert OperatingPoint.from_meta(back.meta) == point and dict(back.meta) == point.to_meta()
    assert (back.first_index, back.fs_hz, back.flags, back.gap_samples) == (123_456, 100_000.0, BlockFlags.GAP, 17)
    for c, x in blk.channels.items():
        assert back.channels[c].dtype == x.dtype and back.channels[c].tobytes() == x.tobytes()
    from mcap.writer import Writer

    with open(tmp_path / "z.mcap", "wb") as fh:  # the received bytes, as they came, in a log
        w = Writer(fh)
        w.start(profile="hystbench")
        schema = w.register_schema(SCHEMAS[RAW][0], "jsonschema", schema_bytes(RAW))
        w.add_message(w.register_channel(RAW, "json", schema), log_time=0, data=payload, publish_time=0)
        w.finish()
    (logged,) = iter_blocks(tmp_path / "z.mcap")
    assert (logged.first_index, logged.flags, logged.gap_samples, dict(logged.meta)) == \
        (back.first_index, back.flags, back.gap_samples, dict(back.meta))
    assert all(logged.channels[c].tobytes() == x.tobytes() for c, x in blk.channels.items())


def service(tmp_path: Path, extra: str = "", **kw) -> tuple[BenchService, int]:
    port = free_port()
    toml = tmp_path / "daemon.toml"
    toml.write_text(f'[daemon]\nbench = "t"\nlog_dir = "{tmp_path.as_posix()}"\nstats_interval_s = 0.3\n'
                    f'[source]\nkind = "sim"\n[zenoh]\nlisten = ["tcp/127.0.0.1:{port}"]\n'
                    f'[sweep]\nfrequencies_hz = [160.0, 320.0]\ndwell_s = 0.4\n' + extra, encoding="utf-8")
    return BenchService(load_daemon_config(toml), **kw).start(), port


def client(port: int, **auth):
    return open_session(load_zenoh_config(peer_config(connect=[f"tcp/127.0.0.1:{port}"], **auth)))


def test_bench_on_zenoh_publishes_answers_and_obeys(tmp_path: Path) -> None:
    svc, port = service(tmp_path)
    s = client(port)
    try:
        raw = Subscription(s, "hystbench/t/raw/**")
        est = Subscription(s, "hystbench/t/estimate")
        status = Subscription(s, "hystbench/t/status")
        stats = Subscription(s, "hystbench/t/stats")
        health = answered(s, "hystbench/t/health")
        assert health and health[0]["state"] == "running" and health[0]["bench"] == "t"
        assert query_json(s, "hystbench/t/config")[0]["sweep"]["frequencies_hz"] == [160.0, 320.0]
        with pytest.raises(BenchError, match="unknown command"):
            send_command(s, "t", "self_destruct")
        with pytest.raises(BenchError, match="frequencies"):
            send_command(s, "t", "start_sweep", {"frequencies_hz": [1e9]})
        assert send_command(s, "t", "start_sweep")["points"] == 2
        with pytest.raises(BenchError, match="a sweep is running"):
            send_command(s, "t", "start_sweep")
        got = [Estimate.from_json(json.loads(p)) for _, p, _ in est.iter(count=4, seconds=HANG_S)]
        assert len(got) == 4 and all(not e.error for e in got)
        assert {e.nominal_frequency_hz for e in got} <= {160.0, 320.0}
        k, payload, _ = raw.get(HANG_S)
        blk = decode(payload, k)
        assert k == "hystbench/t/raw" and blk.n == 1000 and blk.fs_hz == 100_000.0
        assert OperatingPoint.from_meta(blk.meta).current_pp_a == 1.4  # what was played: the configured default
        assert list(blk.channels) == ["current_A", "force_N", "flux_Wb", "sense_V", "command_V"]
        assert seen(status, "sweep_point")
        st_ = json.loads(stats.get(HANG_S)[1])
        assert st_["stages"]["source"]["samples"] > 0 and "latency_ms_p99" in st_["stages"]["publish"]
        assert send_command(s, "t", "stop_sweep")["stopped"]
        assert send_command(s, "t", "set_excitation", {"frequency_hz": 80.0})["applied"] == {"frequency_hz": 80.0}
        with pytest.raises(BenchError, match="unknown argument"):
            send_command(s, "t", "set_excitation", {"volume": 11})
    finally:
        s.close()
        paths = svc.stop()
    assert paths and paths[0].stat().st_size > 0


def _acl_config(tmp_path: Path) -> Path:
    """The shipped ACL config with its users file pointed at a temporary one."""
    users = tmp_path / "users.txt"
    users.write_text("operator:op-secret\nviewer:view-secret\n", encoding="utf-8")
    os.chmod(users, 0o600)
    import zenoh

    cfg = zenoh.Config.from_file(str(CONFIG_DIR / "zenoh-acl.json5"))
    assert json.loads(cfg.get_json("access_control/default_permission")) == "deny"
    text = (CONFIG_DIR / "zenoh-acl.json5").read_text(encoding="utf-8")
    out = tmp_path / "zenoh-acl.json5"
    out.write_text(text.replace("/etc/hystbench/zenoh-users.txt", users.as_posix()), encoding="utf-8")
    return out


def test_access_control_denies_commands_to_unlisted_subjects(tmp_path: Path) -> None:
    acl = _acl_config(tmp_path)
    port = free_port()
    toml = tmp_path / "acl.toml"
    toml.write_text(f'[daemon]\nbench = "t"\nlog_dir = "{tmp_path.as_posix()}"\n[source]\nkind = "sim"\n'
                    f'[zenoh]\nconfig = "{acl.as_posix()}"\nlisten = ["tcp/127.0.0.1:{port}"]\n'
                    f'[sweep]\nfrequencies_hz = [320.0]\ndwell_s = 5.0\n', encoding="utf-8")
    svc = BenchService(load_daemon_config(toml)).start()
    viewer = client(port, user="viewer", password="view-secret")
    try:
        status = Subscription(viewer, "hystbench/t/status")
        assert answered(viewer, "hystbench/t/health")[0]["state"] == "running"  # may watch
        with pytest.raises(BenchError, match="access control"):
            send_command(viewer, "t", "start_sweep", timeout_s=1.0)
        assert svc.state == "running" and not svc.source.rig.output_enabled  # nothing was driven
        assert "sweep_started" not in [json.loads(p)["event"] for _, p, _ in status.iter(seconds=0.3)]
        operator = client(port, user="operator", password="op-secret")
        try:
            assert send_command(operator, "t", "start_sweep", timeout_s=HANG_S)["points"] == 1
            assert seen(status, "sweep_started")  # the viewer sees it happen, but could not start it
        finally:
            operator.close()
        intruder = client(port, user="nobody", password="x")  # not in the users file: not connected
        try:
            assert query_json(intruder, "hystbench/t/health", timeout_s=0.5) == []
        finally:
            intruder.close()
    finally:
        viewer.close()
        svc.stop()


def _outcome(call: Callable[[], object]) -> object:
    """What ``call()`` returned, or the BenchError it raised."""
    try:
        return call()
    except BenchError as err:
        return err


def test_replies_that_are_not_the_daemons_json_through_real_queryables() -> None:
    """Under load `hystbench ctl` once printed only "Expecting value": query_json fed zenoh's own
    error reply ``Timeout`` (a queryable that did not answer in time, as when access control drops
    the query) to json.loads.  Now: a reply that is no JSON object is a NetworkError naming the
    key; a plain-text error reply is a refusal (CommandRefused, with its text); zenoh's Timeout is
    "nobody answered" (NoReply naming the key).  Each through a real queryable on loopback."""
    port = free_port()
    server = open_session(load_zenoh_config(None, listen=[f"tcp/127.0.0.1:{port}"]))
    silent_asked = threading.Event()
    held: list = []  # queries never answered: zenoh times the querier out

    def text(query) -> None:
        with query:
            query.reply(query.key_expr, b"<html>not json</html>", encoding="text/html")

    def plain_error(query) -> None:
        with query:
            query.reply_err(b"plain failure")

    def silent(query) -> None:
        held.append(query)
        silent_asked.set()

    decls = [server.declare_queryable("hystbench/x/health", text),
             server.declare_queryable("hystbench/x/cmd/stop_sweep", plain_error),
             server.declare_queryable("hystbench/x/cmd/output", silent)]
    s = client(port)
    try:
        # a new session may not know the queryables yet: such a query finds no one and comes back
        # at once with no reply (NoReply, []); asked again until it reaches them (bounded: a hang)
        deadline = Deadline(HANG_S)
        got = _outcome(lambda: query_json(s, "hystbench/x/health", timeout_s=HANG_S))
        while got == [] and not deadline.expired:
            got = _outcome(lambda: query_json(s, "hystbench/x/health", timeout_s=HANG_S))
        assert isinstance(got, NetworkError) and not isinstance(got, NoReply), got
        assert str(got).startswith("hystbench/x/health: the reply is not a JSON object: '<html>not json</html>'")
        got = _outcome(lambda: send_command(s, "x", "stop_sweep", timeout_s=HANG_S))
        while isinstance(got, NoReply) and not deadline.expired:
            got = _outcome(lambda: send_command(s, "x", "stop_sweep", timeout_s=HANG_S))
        assert isinstance(got, CommandRefused) and got.reply == {"ok": False, "error": "plain failure"}, got
        assert str(got) == "bench 'x': cmd/stop_sweep refused: plain failure"
        got = _outcome(lambda: send_command(s, "x", "output", {"on": True}, timeout_s=0.5))
        while not silent_asked.is_set() and not deadline.expired:  # until a query was routed to it
            got = _outcome(lambda: send_command(s, "x", "output", {"on": True}, timeout_s=0.5))
        assert silent_asked.is_set()
        assert isinstance(got, NoReply) and "no reply to cmd/output within 0.5 s" in str(got), got
        assert query_json(s, "hystbench/x/cmd/output", {"on": True}, timeout_s=0.5) == []  # routed, timed out
    finally:
        held.clear()
        s.close()
        for d in decls:
            d.undeclare()
        server.close()


def test_watch_prints_live_estimates_from_another_process(tmp_path: Path) -> None:
    # The output stays on until the watcher has its three estimates: a sweep of fixed length
    # could end before a subprocess on a busy machine has subscribed.  --seconds and timeout only
    # turn a hang into a failure.
    svc, port = service(tmp_path)
    try:
        svc.command("set_excitation", {"frequency_hz": 320.0, "current_pp_a": 1.0})
        svc.command("output", {"on": True})
        proc = subprocess.run([sys.executable, "-m", "hystbench", "watch",
                               "hystbench/t/estimate", "--connect", f"tcp/127.0.0.1:{port}", "--count", "3",
                               "--seconds", "300"], capture_output=True, text=True, timeout=400, cwd=ROOT)
    finally:
        svc.stop()
    assert proc.returncode == 0, proc.stderr
    lines = proc.stdout.strip().splitlines()
    assert len(lines) == 3 and all("hysteresis" in ln and "deg" in ln for ln in lines)
