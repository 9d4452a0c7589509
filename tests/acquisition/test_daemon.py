"""The daemon as a real process: systemd notify (READY, WATCHDOG, RELOADING, STOPPING), SIGHUP
reload (a bad file refused, the old config kept), SIGTERM (exit 0, a finished log), a bad config
at start (exit 2 naming the key), and ``kill -9`` mid-recording followed by ``recover``.
Each daemon listens on an ephemeral 127.0.0.1 port; every wait is bounded."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest
from mcap.reader import make_reader

from hystbench.acquisition import sd_notify
from hystbench.acquisition.daemon import load_daemon_config
from hystbench.acquisition.mcaplog import RAW, STATUS, iter_blocks, iter_log, log_metadata, recover
from hystbench.acquisition.zenoh_bus import free_port, load_zenoh_config, open_session, peer_config, query_json
from hystbench.errors import ConfigError, RecordingError

ROOT = Path(__file__).resolve().parents[2]
FS = 100_000.0


def write_config(path: Path, port: int, logs: Path, *, periods: float = 10.0, extra: str = "") -> None:
    path.write_text(f'[daemon]\nbench = "d1"\nlog_dir = "{logs.as_posix()}"\nstats_interval_s = 0.3\n'
                    f'[source]\nkind = "sim"\n[estimation]\nperiods = {periods}\n[recording]\nflush_interval_s = 0.25\n'
                    f'[zenoh]\nlisten = ["tcp/127.0.0.1:{port}"]\n'
                    f'[sweep]\nfrequencies_hz = [320.0]\ndwell_s = 30.0\nautostart = true\n' + extra,
                    encoding="utf-8")


class Daemon:
    """The daemon in a subprocess with a notify socket of our own."""

    def __init__(self, tmp: Path, config: Path) -> None:
        self.sock_path = tmp / "notify.sock"
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        self.sock.bind(str(self.sock_path))
        self.messages: list[str] = []
        self.stderr_path = tmp / "daemon.stderr"
        env = dict(os.environ, NOTIFY_SOCKET=str(self.sock_path), WATCHDOG_USEC="400000", PYTHONUNBUFFERED="1")
        env.pop("WATCHDOG_PID", None)
        self.proc = subprocess.Popen([sys.executable, "-m", "hystbench", "daemon",
                                      "--config", str(config)], cwd=ROOT, env=env,
                                     stdout=subprocess.DEVNULL, stderr=open(self.stderr_path, "wb"))

    def wait_for(self, field: str, timeout_s: float = 20.0) -> float:
        """Read notifications until one holds ``field``; returns when it came (monotonic)."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            self.sock.settimeout(max(0.01, min(0.5, deadline - time.monotonic())))
            try:
                msg = self.sock.recv(4096).decode()
            except socket.timeout:
                if self.proc.poll() is not None:
                    break
                continue
            self.messages.append(msg)
            if field in msg.split("\n"):
                return time.monotonic()
        raise AssertionError(f"no {field} within {timeout_s} s; got {self.messages[-5:]}; "
                             f"exit {self.proc.poll()}; stderr: {self.stderr()[-2000:]}")

    def stderr(self) -> str:
        return self.stderr_path.read_text(errors="replace")

    def close(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait(timeout=10)
        self.sock.close()


def test_daemon_notify_reload_refusal_and_clean_stop(tmp_path: Path) -> None:
    port, logs, cfg = free_port(), tmp_path / "logs", tmp_path / "daemon.toml"
    write_config(cfg, port, logs)
    d = Daemon(tmp_path, cfg)
    session = None
    try:
        d.wait_for("READY=1")
        d.wait_for("WATCHDOG=1", 3.0)
        session = open_session(load_zenoh_config(peer_config(connect=[f"tcp/127.0.0.1:{port}"])))

        def config() -> dict:
            deadline = time.monotonic() + 10
            while time.monotonic() < deadline:
                got = query_json(session, "hystbench/d1/config", timeout_s=1.0)
                if got:
                    return got[0]
            raise AssertionError("no reply from hystbench/d1/config")

        assert config()["estimation"]["periods"] == 10.0
        write_config(cfg, port, logs, periods=6.0)  # a good change
        d.proc.send_signal(signal.SIGHUP)
        d.wait_for("RELOADING=1", 5.0)
        d.wait_for("READY=1", 15.0)
        assert config()["estimation"]["periods"] == 6.0
        cfg.write_text(cfg.read_text().replace("periods = 6.0", 'periods = "ten"'))  # a bad one
        d.proc.send_signal(signal.SIGHUP)
        d.wait_for("RELOADING=1", 5.0)
        d.wait_for("READY=1", 15.0)
        assert config()["estimation"]["periods"] == 6.0  # still the running one
        time.sleep(0.3)
        health = query_json(session, "hystbench/d1/health", timeout_s=2.0)[0]
        assert health["state"] in ("running", "sweeping") and health["samples"] > 0, health
        d.proc.send_signal(signal.SIGTERM)
        assert d.proc.wait(timeout=20) == 0
        d.wait_for("STOPPING=1", 1.0)
    finally:
        if session is not None:
            session.close()
        d.close()
    err = d.stderr()
    assert "reload refused" in err and "[estimation] periods" in err and "must be a number" in err
    parts = sorted(logs.glob("*.mcap"))
    assert len(parts) == 2  # one log per configuration that ran
    for p in parts:  # both finished: summary and footer written
        with open(p, "rb") as fh:
            assert make_reader(fh).get_summary() is not None
    events = [m.json()["event"] for m in iter_log(parts[1], [STATUS])]
    assert "reloaded" in events and "reload_refused" in events and events[-1] == "stopping"
    assert log_metadata(parts[1])["config"]["estimation"]["periods"] == 6.0
    assert sum(b.n for b in iter_blocks(parts[1])) > 0


def test_bad_config_at_start_is_refused_naming_the_key(tmp_path: Path) -> None:
    cfg = tmp_path / "bad.toml"
    cfg.write_text('[daemon]\nbench = "d1"\n[recording]\ncompresion = "zstd"\n', encoding="utf-8")
    proc = subprocess.run([sys.executable, "-m", "hystbench", "daemon", "--config",
                           str(cfg)], cwd=ROOT, capture_output=True, text=True, timeout=30)
    assert proc.returncode == 2
    assert "[recording]: unknown key 'compresion'" in proc.stderr and str(cfg) in proc.stderr


@pytest.mark.parametrize("text, match", [
    ('[source]\nrig = "nope"\n', r"\[source\] rig: unknown rig 'nope'"),
    ('[source]\nfs_hz = -1\n', r"\[source\] fs_hz: must be > 0"),
    ('[source]\nblock_samples = 10.5\n', r"\[source\] block_samples: must be int"),
    ('[source]\npace = "fast"\n', r"\[source\] pace: must be one of realtime, max"),
    ('[sweep]\nfrequencies_hz = []\n', r"\[sweep\] frequencies_hz: must be a non-empty list"),
    ('[daemon]\nbench = "a/b"\n', r"\[daemon\] bench: bench name 'a/b'"),
    ('[zenoh]\nlisten = [7447]\n', r"\[zenoh\] listen: must be a list of endpoints"),
    ('[nonsense]\n', r"unknown section \[nonsense\]"),
    ('[estimation]\nenabled = false\n[compensator]\nenabled = true\nlearn = true\n',
     r"\[compensator\] enabled needs \[estimation\] enabled"),
    ('[daemon\n', r"not valid TOML"),
])
def test_config_errors_name_file_and_key(tmp_path: Path, text: str, match: str) -> None:
    cfg = tmp_path / "c.toml"
    cfg.write_text(text, encoding="utf-8")
    with pytest.raises(ConfigError, match=match):
        load_daemon_config(cfg)


def test_shipped_daemon_toml_is_valid_and_states_the_defaults() -> None:
    from hystbench.config import CONFIG_DIR

    assert load_daemon_config(CONFIG_DIR / "daemon.toml").values == load_daemon_config(None).values


def test_kill_9_mid_recording_then_recover_loses_at_most_a_second(tmp_path: Path) -> None:
    port, logs, cfg = free_port(), tmp_path / "logs", tmp_path / "daemon.toml"
    write_config(cfg, port, logs)
    d = Daemon(tmp_path, cfg)
    session = open_session(load_zenoh_config(peer_config(connect=[f"tcp/127.0.0.1:{port}"])))
    try:
        d.wait_for("READY=1")
        time.sleep(2.5)
        health = []
        deadline = time.monotonic() + 5
        while not health and time.monotonic() < deadline:
            health = query_json(session, "hystbench/d1/health", timeout_s=1.0)
        produced = health[0]["samples"]  # samples the source had produced just before the kill
        d.proc.send_signal(signal.SIGKILL)
        assert d.proc.wait(timeout=10) == -signal.SIGKILL
    finally:
        session.close()
        d.close()
    (log,) = list(logs.glob("*.mcap"))
    with pytest.raises(RecordingError, match="hystbench recover"):
        list(iter_blocks(log))
    rep = recover(log)
    assert not rep.complete and rep.by_topic[RAW] > 0
    blocks = list(iter_blocks(rep.out))
    assert blocks[0].first_index == 0
    assert all(b.first_index == a.end_index for a, b in zip(blocks, blocks[1:]))  # contiguous
    end = blocks[-1].end_index
    assert end >= produced - FS * 1.0, f"salvaged up to sample {end}, the source was at {produced}"
    assert log_metadata(rep.out)["recording"]["rig"] == "ecore_pm"


def test_sd_notify_without_systemd_and_watchdog_period(monkeypatch, tmp_path: Path) -> None:
    monkeypatch.delenv("NOTIFY_SOCKET", raising=False)
    assert sd_notify.notify("READY=1") is False
    monkeypatch.setenv("WATCHDOG_USEC", "10000000")
    monkeypatch.setenv("WATCHDOG_PID", str(os.getpid()))
    assert sd_notify.watchdog_interval_s() == 5.0
    monkeypatch.setenv("WATCHDOG_PID", "1")
    assert sd_notify.watchdog_interval_s() is None
    monkeypatch.setenv("NOTIFY_SOCKET", str(tmp_path / "absent.sock"))
    assert sd_notify.notify("READY=1") is False  # never raises
    monkeypatch.delenv("WATCHDOG_PID")
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind(str(tmp_path / "n.sock"))
    sock.settimeout(2.0)
    monkeypatch.setenv("NOTIFY_SOCKET", str(tmp_path / "n.sock"))
    n = sd_notify.Notifier()
    assert n.ping(now=100.0) and not n.ping(now=102.0) and n.ping(now=105.5)
    assert sock.recv(100) == b"WATCHDOG=1"
    sock.close()


def test_daemon_default_source_is_the_emulated_bench(tmp_path: Path) -> None:
    """No [source] table: the simulated rig behind the emulated instruments, through the drivers."""
    from hystbench.acquisition.zenoh_bus import Subscription, send_command

    port, logs, cfg = free_port(), tmp_path / "logs", tmp_path / "daemon.toml"
    cfg.write_text(f'[daemon]\nbench = "d2"\nlog_dir = "{logs.as_posix()}"\n'
                   f'[zenoh]\nlisten = ["tcp/127.0.0.1:{port}"]\n', encoding="utf-8")
    d = Daemon(tmp_path, cfg)
    session = None
    try:
        d.wait_for("READY=1")
        session = open_session(load_zenoh_config(peer_config(connect=[f"tcp/127.0.0.1:{port}"])))
        est = Subscription(session, "hystbench/d2/estimate")
        time.sleep(0.3)
        health = query_json(session, "hystbench/d2/health", timeout_s=2.0)[0]
        assert "emulated instruments" in health["source"]
        send_command(session, "d2", "start_sweep", {"frequencies_hz": [320.0], "dwell_s": 5.0})
        import json

        got = [json.loads(p) for _, p, _ in est.iter(count=8, seconds=8.0)]
        assert sum(1 for e in got if not e["error"]) >= 3
        d.proc.send_signal(signal.SIGTERM)
        assert d.proc.wait(timeout=20) == 0
    finally:
        if session is not None:
            session.close()
        d.close()
    (log,) = list(logs.glob("*.mcap"))
    assert sum(b.n for b in iter_blocks(log)) > 50_000


def test_after_the_compensator_switched_the_output_off_it_stays_off(tmp_path: Path) -> None:
    """A learning loop that stopped itself switched the output off: a sweep point or an 'output on'
    command must not drive the bench open loop; a reload (a new service) clears it."""
    from hystbench.acquisition.daemon import BenchService
    from hystbench.acquisition.pipeline import CompensatorHook

    cfg = tmp_path / "c.toml"
    cfg.write_text('[source]\nkind = "sim"\npace = "max"\n[zenoh]\nenabled = false\n[recording]\nenabled = false\n'
                   '[estimation]\nenabled = false\n', encoding="utf-8")
    svc = BenchService(load_daemon_config(cfg)).start()
    try:
        assert svc.command("output", {"on": True}) == {"output_on": True}  # nothing tripped yet
        hook = CompensatorHook(type("Stopped", (), {"update": lambda self, e: {"output_off": True,
                                                                                "status": "stopped: diverging"}})(),
                               svc.source)
        assert hook({"error": None}) == {"status": "stopped: diverging", "output_switched_off": True}
        deadline = time.monotonic() + 5.0
        while svc.source.rig.output_enabled and time.monotonic() < deadline:
            time.sleep(0.02)
        assert not svc.source.rig.output_enabled  # applied by the source at its next block
        svc.pipeline.compensator = hook
        for verb, args in (("output", {"on": True}), ("start_sweep", {})):
            with pytest.raises(ConfigError, match=rf"{verb}: refused, the compensator switched the output off "
                                                  r"\(stopped: diverging\)"):
                svc.command(verb, args)
        assert svc.command("output", {"on": False}) == {"output_on": False}  # off is always allowed
    finally:
        svc.stop()
