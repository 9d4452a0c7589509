"""The daemon as a real process: systemd notify (READY, WATCHDOG, RELOADING, STOPPING), SIGHUP
reload (a bad file refused, the old config kept), SIGTERM (exit 0, a finished log), a bad config
at start (exit 2 naming the key), and ``kill -9`` mid-recording followed by ``recover``.
Each daemon listens on an ephemeral 127.0.0.1 port; every wait is bounded."""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
from pathlib import Path

import pytest
from mcap.reader import make_reader

from hystbench.acquisition.zenoh_bus import free_port, load_zenoh_config, open_session, peer_config, query_json
from hystbench.blocks import BlockFlags
from hystbench.deadline import Deadline
from hystbench.errors import CommandRefused, ConfigError, RecordingError
from hystbench.formats.mcaplog import RAW, STATUS, iter_blocks, iter_log, log_metadata, recover
from hystbench.messages import CompensatorUpdate, Estimate
from hystbench.service import sd_notify
from hystbench.service.daemon_config import load_daemon_config

from .conftest import HANG_S, ROOT, Daemon, health_when

pytestmark = pytest.mark.slow(45)  # ~45 s: handed to a worker before lighter files (tests/conftest.py)

FS = 100_000.0
#: SIGTERM's bound for these daemons: their clean stop is under test, not the bound (test_log_disk
#: tests it).  Beside two busy loops, finishing a log took past the 4.5 s default (exit 1, by design).
STOP = f"stop_timeout_s = {HANG_S}"


def write_config(path: Path, port: int, logs: Path, *, periods: float = 10.0, extra: str = "") -> None:
    path.write_text(f'[daemon]\nbench = "d1"\nlog_dir = "{logs.as_posix()}"\nstats_interval_s = 0.3\n{STOP}\n'
                    f'[source]\nkind = "sim"\n[estimation]\nperiods = {periods}\n[recording]\nflush_interval_s = 0.25\n'
                    'idle_raw = "full"\n'  # every sample: the crash test counts them
                    f'[zenoh]\nlisten = ["tcp/127.0.0.1:{port}"]\n'
                    f'[sweep]\nfrequencies_hz = [320.0]\ndwell_s = 30.0\nautostart = true\n' + extra,
                    encoding="utf-8")


def test_daemon_notify_reload_refusal_and_clean_stop(tmp_path: Path) -> None:
    port, logs, cfg = free_port(), tmp_path / "logs", tmp_path / "daemon.toml"
    write_config(cfg, port, logs)
    d = Daemon(tmp_path, cfg)
    session = None
    try:
        d.wait_for("READY=1")
        d.wait_for("WATCHDOG=1")
        session = open_session(load_zenoh_config(peer_config(connect=[f"tcp/127.0.0.1:{port}"])))

        def config() -> dict:
            deadline = Deadline(HANG_S)
            while not deadline.expired:
                got = query_json(session, "hystbench/d1/config", timeout_s=1.0)
                if got:
                    return got[0]
            raise AssertionError("no reply from hystbench/d1/config")

        assert config()["estimation"]["periods"] == 10.0
        write_config(cfg, port, logs, periods=6.0)  # a good change
        d.proc.send_signal(signal.SIGHUP)
        d.wait_for("RELOADING=1")
        d.wait_for("READY=1")
        assert config()["estimation"]["periods"] == 6.0
        cfg.write_text(cfg.read_text().replace("periods = 6.0", 'periods = "ten"'))  # a bad one
        d.proc.send_signal(signal.SIGHUP)
        d.wait_for("RELOADING=1")
        d.wait_for("READY=1")
        assert config()["estimation"]["periods"] == 6.0  # still the running one
        health = health_when(session, "d1", lambda h: h["samples"] > 0)
        assert health["state"] in ("running", "sweeping"), health
        d.proc.send_signal(signal.SIGTERM)
        assert d.proc.wait(timeout=20) == 0
        d.wait_for("STOPPING=1")  # sent before it exited: already there
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


def test_kill_9_mid_recording_then_recover_keeps_everything_flushed(tmp_path: Path) -> None:
    """What the recorder reported on disk before the kill is salvaged whole: the loss is bounded by
    the flush interval (0.25 s here), whatever the machine's load, and nothing is waited on time."""
    port, logs, cfg = free_port(), tmp_path / "logs", tmp_path / "daemon.toml"
    write_config(cfg, port, logs)
    d = Daemon(tmp_path, cfg)
    session = open_session(load_zenoh_config(peer_config(connect=[f"tcp/127.0.0.1:{port}"])))
    try:
        d.wait_for("READY=1")
        flushed = health_when(session, "d1", lambda h: h["raw_flushed_to"] >= 2.5 * FS)["raw_flushed_to"]
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
    # contiguous but where the log itself says samples are missing: live, a record stage that fell
    # behind (a loaded machine) loses counted samples, flagged GAP on the next block; recover loses none
    assert all(b.first_index == a.end_index + b.gap_samples for a, b in zip(blocks, blocks[1:]))
    assert all(b.flags & BlockFlags.GAP for b in blocks if b.gap_samples)
    end = blocks[-1].end_index
    assert end >= flushed, f"salvaged up to sample {end}, the recorder had flushed up to {flushed}"
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
    cfg.write_text(f'[daemon]\nbench = "d2"\nlog_dir = "{logs.as_posix()}"\n{STOP}\n'
                   f'[zenoh]\nlisten = ["tcp/127.0.0.1:{port}"]\n', encoding="utf-8")
    d = Daemon(tmp_path, cfg)
    session = None
    try:
        d.wait_for("READY=1")
        session = open_session(load_zenoh_config(peer_config(connect=[f"tcp/127.0.0.1:{port}"])))
        est = Subscription(session, "hystbench/d2/estimate")
        health = health_when(session, "d2", lambda h: True)
        assert "emulated instruments" in health["source"]
        send_command(session, "d2", "start_sweep", {"frequencies_hz": [320.0], "dwell_s": 600.0})
        # eight estimates, however long they take (the emulated bench runs slower than real time on a
        # busy machine: a wall-clock window would see fewer); the timeout only turns a hang into a failure
        got = [json.loads(p) for _, p, _ in est.iter(count=8, seconds=HANG_S)]
        errors = [e["error"] for e in got if e["error"]]
        assert len(got) == 8 and len(errors) <= 5, errors
        d.proc.send_signal(signal.SIGTERM)
        assert d.proc.wait(timeout=20) == 0
    finally:
        if session is not None:
            session.close()
        d.close()
    parts = sorted(logs.glob("*.mcap"))  # a second part is a fault's restart: say which fault
    said = [m.json() for part in parts for m in iter_log(part, [STATUS])]
    assert len(parts) == 1, [s.get("message") for s in said if s.get("level") == "error"]
    assert sum(b.n for b in iter_blocks(parts[0])) > 50_000


def test_after_the_compensator_switched_the_output_off_it_stays_off(tmp_path: Path) -> None:
    """A learning loop that stopped itself switched the output off: a sweep point or an 'output on'
    command must not drive the bench open loop; a reload (a new service) clears it."""
    from hystbench.acquisition.pipeline import CompensatorHook
    from hystbench.service.service import BenchService

    cfg = tmp_path / "c.toml"
    cfg.write_text('[source]\nkind = "sim"\npace = "max"\n[zenoh]\nenabled = false\n[recording]\nenabled = false\n'
                   '[estimation]\nenabled = false\n', encoding="utf-8")
    svc = BenchService(load_daemon_config(cfg)).start()
    try:
        assert svc.command("output", {"on": True}) == {"output_on": True}  # nothing tripped yet
        stopped = CompensatorUpdate({"status": "stopped: diverging"}, output_off=True)
        hook = CompensatorHook(type("Stopped", (), {"update": lambda self, e: stopped})(), svc.source)
        assert hook(Estimate(0, 1000, 0, 320.0, 1.4)) == {"status": "stopped: diverging", "output_switched_off": True}
        # applied by the source before its next block: two blocks on, it is (the timeout bounds a hang)
        assert svc.pipeline.after_samples(2 * svc.source.block_samples).wait(HANG_S)
        assert not svc.source.rig.output_enabled
        svc.pipeline.compensator = hook
        for verb, args in (("output", {"on": True}), ("start_sweep", {})):
            with pytest.raises(CommandRefused, match=rf"{verb}: refused, the compensator switched the output off "
                                                     r"\(stopped: diverging\)"):
                svc.command(verb, args)
        assert svc.command("output", {"on": False}) == {"output_on": False}  # off is always allowed
    finally:
        svc.stop()


# --- issue 16: a daemon that survives any command, one per bench, its logs in its state directory --------
def test_bad_commands_are_refused_and_the_daemon_stays_up(tmp_path: Path) -> None:
    """The issue's two commands (50 A-pp on a 2 A bench) killed the daemon with exit 1; now each is
    refused with the reason and the daemon answers the next one.  No [daemon] log_dir: the log
    goes to $STATE_DIRECTORY/logs, and the daemon says so on start-up."""
    from hystbench.acquisition.zenoh_bus import send_command
    from hystbench.errors import BenchError

    port, cfg, state = free_port(), tmp_path / "daemon.toml", tmp_path / "state"
    cfg.write_text(f'[daemon]\nbench = "d3"\n{STOP}\n[zenoh]\nlisten = ["tcp/127.0.0.1:{port}"]\n', encoding="utf-8")
    d = Daemon(tmp_path, cfg, state=state)
    session = None
    try:
        d.wait_for("READY=1")
        session = open_session(load_zenoh_config(peer_config(connect=[f"tcp/127.0.0.1:{port}"])))
        for verb, args in (("set_excitation", {"frequency_hz": 320, "current_pp_a": 50}),
                           ("start_sweep", {"frequencies_hz": [160], "current_pp_a": 50})):
            with pytest.raises(BenchError, match=r"refused: .*25 A exceeds the bench's limit of 1\.71 A"):
                send_command(session, "d3", verb, args, timeout_s=30.0)
        assert send_command(session, "d3", "set_excitation", {"frequency_hz": 160, "current_pp_a": 1.0},
                            timeout_s=30.0)["ok"]
        health = health_when(session, "d3", lambda h: True)
        assert health["state"] == "running" and health["pid"] == d.proc.pid and health["faults"] == 0
        assert health["log_dir"] == str(state / "logs")
        assert d.proc.poll() is None
        d.proc.send_signal(signal.SIGTERM)
        assert d.proc.wait(timeout=20) == 0
    finally:
        if session is not None:
            session.close()
        d.close()
    (log,) = list((state / "logs").glob("d3-*.mcap"))
    assert f"logs in {state / 'logs'} (default: $STATE_DIRECTORY/logs)" in d.stderr()
    assert log_metadata(log)["config"]["daemon"]["log_dir"] == str(state / "logs")


def test_a_second_daemon_of_the_same_bench_is_refused(tmp_path: Path) -> None:
    """Same bench name, only the port changed: refused with the first one's PID and endpoint
    (the lock file in the shared state directory).  Another state directory but connected over
    zenoh: refused too (the liveliness token)."""
    port1 = free_port()
    first_cfg, second_cfg, third_cfg = tmp_path / "a.toml", tmp_path / "b.toml", tmp_path / "c.toml"
    write_config(first_cfg, port1, tmp_path / "logs")
    first = Daemon(tmp_path, first_cfg, name="1")
    try:
        first.wait_for("READY=1")
        # the other two ports only now: the first daemon's emulators bind ephemeral ports as it starts,
        # and one of them once took a port chosen before it (the third then failed to listen)
        port2, port3 = free_port(), free_port()
        write_config(second_cfg, port2, tmp_path / "logs")
        write_config(third_cfg, port3, tmp_path / "logs3")
        third_cfg.write_text(third_cfg.read_text().replace(
            f'listen = ["tcp/127.0.0.1:{port3}"]', f'listen = ["tcp/127.0.0.1:{port3}"]\nconnect = ["tcp/127.0.0.1:{port1}"]'))
        env = dict(os.environ, STATE_DIRECTORY=str(tmp_path / "state"))
        second = subprocess.run([sys.executable, "-m", "hystbench", "daemon", "--config", str(second_cfg)], cwd=ROOT,
                                env=env, capture_output=True, text=True, timeout=60)
        assert second.returncode == 2
        assert f"bench 'd1' is already served by PID {first.proc.pid} (zenoh tcp/127.0.0.1:{port1}" in second.stderr
        assert "Traceback" not in second.stderr and len(second.stderr.strip().splitlines()) == 1
        env["STATE_DIRECTORY"] = str(tmp_path / "other-state")
        third = subprocess.run([sys.executable, "-m", "hystbench", "daemon", "--config", str(third_cfg)], cwd=ROOT,
                               env=env, capture_output=True, text=True, timeout=60)
        assert third.returncode == 2
        assert f"already served on the zenoh network by PID {first.proc.pid} (zenoh tcp/127.0.0.1:{port1}" \
            in third.stderr, third.stderr
        assert first.proc.poll() is None  # the first one never noticed
    finally:
        first.close()
    assert not list((tmp_path / "logs3").glob("*.mcap"))  # the refused one wrote nothing


def test_a_taken_port_names_the_key_to_change(tmp_path: Path) -> None:
    port = free_port()
    a, b = tmp_path / "a.toml", tmp_path / "b.toml"
    write_config(a, port, tmp_path / "logs")
    b.write_text(a.read_text().replace('bench = "d1"', 'bench = "d9"'), encoding="utf-8")
    first = Daemon(tmp_path, a, name="1")
    try:
        first.wait_for("READY=1")
        env = dict(os.environ, STATE_DIRECTORY=str(tmp_path / "state"))
        second = subprocess.run([sys.executable, "-m", "hystbench", "daemon", "--config", str(b)], cwd=ROOT,
                                env=env, capture_output=True, text=True, timeout=60)
    finally:
        first.close()
    assert second.returncode == 2
    lines = second.stderr.strip().splitlines()
    assert lines == [f"hystbench daemon: error: {b} [zenoh] listen: cannot listen on tcp/127.0.0.1:{port}: address "
                     "already in use (another hystbench daemon or a zenoh router?); change [zenoh] listen"], lines


def test_a_hardware_bench_file_as_config_fails_only_at_connect(tmp_path: Path, monkeypatch) -> None:
    """`hystbench daemon --config bench_hardware.toml` (addresses made local and absent): accepted,
    then one line naming the instrument and its address, exit 1 (systemd may retry: not a bad file).

    Given alone, a bench file runs the daemon's defaults, which listen on zenoh's 7447: the test
    depended on that port being free (another daemon, a router or a parallel run took it, and the
    daemon stopped at its listen endpoint, exit 2).  So: the bench file as --config is, value for
    value, the daemon file that names it as [source] bench_file; that daemon file, plus a free
    port, runs the daemon."""
    text = (ROOT / "hystbench/config/bench_hardware.toml").read_text(encoding="utf-8")
    for old in ("192.168.0.20:5025", "192.168.0.20:5026", "192.168.0.21:5027"):
        text = text.replace(old, f"127.0.0.1:{free_port()}")
    text = text.replace("TCPIP::192.168.0.30::", "TCPIP::127.0.0.1::")  # the (commented) digitiser variant
    for dev in ("/dev/ttyUSB0", "/dev/ttyUSB1", "/dev/ttyS0"):
        text = text.replace(dev, (tmp_path / ("absent-" + dev.rsplit("/", 1)[1])).as_posix())
    assert "192.168." not in text
    bench = tmp_path / "bench_hardware.toml"
    bench.write_text(text, encoding="utf-8")
    monkeypatch.setenv("STATE_DIRECTORY", str(tmp_path / "state"))  # the default log folder, as below
    as_config = load_daemon_config(bench)
    naming = tmp_path / "daemon.toml"
    naming.write_text(f'[source]\nkind = "bench"\nbench_file = "{bench.as_posix()}"\n', encoding="utf-8")
    named = load_daemon_config(naming)
    assert (named.values, named.given) == (as_config.values, as_config.given)
    assert as_config["zenoh"]["listen"] == ["tcp/127.0.0.1:7447"]  # hence the port below
    naming.write_text(naming.read_text() + f'[zenoh]\nlisten = ["tcp/127.0.0.1:{free_port()}"]\n', encoding="utf-8")
    env = dict(os.environ, STATE_DIRECTORY=str(tmp_path / "state"))
    proc = subprocess.run([sys.executable, "-m", "hystbench", "daemon", "--config", str(naming)], cwd=ROOT, env=env,
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 1, proc.stderr
    errors = [ln for ln in proc.stderr.splitlines() if "error:" in ln]
    assert len(errors) == 1 and "Traceback" not in proc.stderr
    assert "current_amplifier" in errors[0] and str(tmp_path / "absent-ttyUSB0") in errors[0]


#: The daemon with a simulated rig that cannot follow 3 A-pp or more (a SimulationError in the source
#: thread, as the E-core's iron gave before it learnt to saturate): a fault the service cannot control.
_RIG_THAT_FAILS = """
import sys
from hystbench.errors import SimulationError
from hystbench.sim_backend.rig import SimulatedRig
read = SimulatedRig.read
def failing(self, n):
    if self.output_enabled and self.current_pp_a >= 3.0:
        raise SimulationError(f"{self.name}: cannot follow {self.current_pp_a:g} A-pp (injected)")
    return read(self, n)
SimulatedRig.read = failing
from hystbench.cli.main import main
sys.exit(main(sys.argv[1:]))
"""


def test_a_fault_in_the_source_is_survived_output_off(tmp_path: Path) -> None:
    """A command within the bench's limit that the simulated rig cannot follow (the simulation
    raises in the source thread) ended the daemon ('pipeline failed ... stopping', exit 1); now
    the daemon's loop publishes the fault, restarts the source and pipeline with the output off,
    and answers the next command."""
    from hystbench.acquisition.zenoh_bus import Subscription, send_command

    port, cfg = free_port(), tmp_path / "daemon.toml"
    cfg.write_text(f'[daemon]\nbench = "d4"\nlog_dir = "{(tmp_path / "logs").as_posix()}"\n{STOP}\n[source]\nkind = "sim"\n'
                   f'[zenoh]\nlisten = ["tcp/127.0.0.1:{port}"]\n', encoding="utf-8")
    d = Daemon(tmp_path, cfg, python=("-c", _RIG_THAT_FAILS))
    session = None
    try:
        d.wait_for("READY=1")
        session = open_session(load_zenoh_config(peer_config(connect=[f"tcp/127.0.0.1:{port}"])))
        status = Subscription(session, "hystbench/d4/status")
        health_when(session, "d4", lambda h: True)  # connected: the subscription sees what follows
        send_command(session, "d4", "set_excitation", {"current_pp_a": 3.0}, timeout_s=30.0)
        send_command(session, "d4", "output", {"on": True}, timeout_s=30.0)
        events: dict[str, dict] = {}
        for _ in range(500):  # bounded; each get waits for the next message
            got = status.get(20.0)
            assert got is not None, f"no 'restarted' event; got {list(events)}; stderr: {d.stderr()[-1500:]}"
            msg = json.loads(got[1])
            events[msg["event"]] = msg
            if msg["event"] == "restarted":
                break
        assert "SimulationError" in events["fault"]["message"] and "output switched off" in events["fault"]["message"]
        assert send_command(session, "d4", "set_excitation", {"current_pp_a": 1.0}, timeout_s=30.0)["ok"]
        health = health_when(session, "d4", lambda h: True)
        assert health["faults"] == 1 and health["state"] == "running" and d.proc.poll() is None
        d.proc.send_signal(signal.SIGTERM)
        assert d.proc.wait(timeout=20) == 0
    finally:
        if session is not None:
            session.close()
        d.close()
    assert len(list((tmp_path / "logs").glob("d4-*.mcap"))) == 2  # the fault started a new part
