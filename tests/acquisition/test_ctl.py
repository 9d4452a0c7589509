"""`hystbench ctl` and `watch` against a real BenchService (simulated rig, cheap) on a loopback zenoh
endpoint: commands take effect, a refusal exits 1 with the daemon's reason, no daemon exits 2
naming the key expression and endpoint, and a silent `watch` says that nobody publishes."""

import json
from pathlib import Path

import pytest

from hystbench.acquisition.zenoh_bus import Subscription, free_port, load_zenoh_config, open_session
from hystbench.cli.main import main
from hystbench.service.daemon_config import load_daemon_config
from hystbench.service.service import BenchService

SAFETY_S = 60.0  # turns a hang into a failure; nothing waits for it on success
SAFETY = str(SAFETY_S)  # ctl --timeout where a reply is expected: it returns as soon as one comes


def run(args: list[str], capsys) -> tuple[int, str, str]:
    try:
        code = main(args)
    except SystemExit as stop:  # argparse's usage error, where main does not turn it into a status
        code = stop.code
    cap = capsys.readouterr()
    return code, cap.out, cap.err


@pytest.fixture
def bench(tmp_path: Path):
    """A running bench 't1' (kind = "sim", no log) and the endpoint it listens on."""
    port = free_port()
    cfg = tmp_path / "d.toml"
    cfg.write_text(f'[daemon]\nbench = "t1"\nlog_dir = "{tmp_path.as_posix()}"\n[source]\nkind = "sim"\n'
                   f'[recording]\nenabled = false\n[zenoh]\nlisten = ["tcp/127.0.0.1:{port}"]\n', encoding="utf-8")
    svc = BenchService(load_daemon_config(cfg)).start()
    try:
        yield svc, f"tcp/127.0.0.1:{port}"
    finally:
        svc.stop()


def test_set_excitation_and_output_reach_the_rig(bench, capsys) -> None:
    svc, ep = bench
    watcher = open_session(load_zenoh_config(None, connect=[ep]))
    sub = Subscription(watcher, "hystbench/t1/estimate")
    try:
        code, out, err = run(["ctl", "--connect", ep, "--bench", "t1", "--timeout", SAFETY, "set_excitation",
                              "--freq", "160", "--ipp", "1.0"], capsys)
        assert code == 0, err
        assert out.startswith("t1: set_excitation ok")
        code, out, err = run(["ctl", "--bench", "t1", "output", "on", "--connect", ep, "--json", "--timeout", SAFETY],
                             capsys)
        assert code == 0, err
        assert json.loads(out) == {"ok": True, "output_on": True}
        # the effect, measured: an estimate at the commanded operating point, output on
        while True:
            item = sub.get(SAFETY_S)
            assert item is not None, "no estimate at 160 Hz arrived"
            e = json.loads(item[1])
            if e["nominal_frequency_hz"] == 160.0 and not e.get("error"):
                break
        assert e["current_pp_a"] == pytest.approx(1.0) and e["frequency_hz"] == pytest.approx(160.0, rel=1e-3)
    finally:
        sub.close()
        watcher.close()


def test_sweep_refusal_status_and_config(bench, capsys) -> None:
    svc, ep = bench
    base = ["ctl", "--connect", ep, "--bench", "t1", "--timeout", SAFETY]
    watcher = open_session(load_zenoh_config(None, connect=[ep]))
    events = Subscription(watcher, "hystbench/t1/status")
    stats = Subscription(watcher, "hystbench/t1/stats")
    try:
        assert stats.get(SAFETY_S) is not None  # declared after status: the daemon knows both subscribers
        code, out, err = run(base + ["start_sweep", "--freqs", "40,80", "--ipp", "1.0", "--dwell", "30"], capsys)
        assert code == 0, err
        assert "points 2" in out and "duration_s 60" in out
        while (item := events.get(SAFETY_S)) is not None and json.loads(item[1])["event"] != "sweep_started":
            pass
        assert item is not None, "no sweep_started"
    finally:
        events.close()
        stats.close()
        watcher.close()
    code, out, err = run(base + ["start_sweep"], capsys)  # one is running: the daemon refuses
    assert code == 1 and out == ""
    assert "hystbench ctl: bench 't1' refused start_sweep:" in err and "a sweep is running" in err
    code, out, err = run(base + ["status"], capsys)
    assert code == 0 and out.startswith("t1: sweeping; output ") and "; source " in out
    code, out, err = run(base + ["stop_sweep", "--json"], capsys)
    assert code == 0 and json.loads(out)["ok"] is True
    code, out, err = run(base + ["config", "--json"], capsys)
    cfg = json.loads(out)
    assert code == 0 and cfg["daemon"]["bench"] == "t1" and cfg["source"]["kind"] == "sim"
    code, out, err = run(base + ["health"], capsys)
    assert code == 0 and "state: running" in out.splitlines()


def test_bad_arguments_exit_2_before_anything_is_sent(capsys) -> None:
    code, out, err = run(["ctl", "--connect", "tcp/127.0.0.1:9", "set_excitation"], capsys)
    assert code == 2 and "set_excitation: give at least one of --freq, --ipp, --offset" in err
    code, out, err = run(["ctl", "start_sweep", "--freqs", "40,fast"], capsys)
    assert code == 2 and "--freqs" in err


def test_no_daemon_exits_2_naming_key_and_endpoint(capsys) -> None:
    ep = f"tcp/127.0.0.1:{free_port()}"  # nobody listens there
    code, out, err = run(["ctl", "--connect", ep, "--bench", "nobody", "--timeout", "1", "status"], capsys)
    assert code == 2 and out == ""
    assert f"hystbench ctl: error: no daemon answered on hystbench/nobody/health via {ep} within 1 s" in err
    code, out, err = run(["ctl", "--connect", ep, "--bench", "nobody", "--timeout", "1", "output", "off"], capsys)
    assert code == 2 and f"on hystbench/nobody/cmd/output via {ep}" in err


def test_watch_says_once_that_no_publisher_is_seen(capsys) -> None:
    ep = f"tcp/127.0.0.1:{free_port()}"
    code, out, err = run(["watch", "hystbench/none/estimate", "--connect", ep, "--quiet-after", "0.2",
                          "--seconds", "1"], capsys)
    assert code == 1 and out == ""  # nothing came: issue 30
    lines = [ln for ln in err.splitlines() if "no publisher seen" in ln]
    assert len(lines) == 1
    assert f"no publisher seen on hystbench/none/estimate via {ep}" in lines[0] and "still waiting" in lines[0]


def test_watch_with_a_publisher_says_nothing_about_silence(bench, capsys) -> None:
    svc, ep = bench
    code, out, err = run(["watch", "hystbench/t1/stats", "--connect", ep, "--count", "1", "--quiet-after", "30",
                          "--seconds", str(SAFETY_S)], capsys)
    assert code == 0 and out.startswith("hystbench/t1/stats ")
    assert "no publisher" not in err


def test_ctl_with_a_client_config_under_access_control(tmp_path: Path, capsys) -> None:
    """The shipped ACL config: a viewer's command is dropped (exit 2, says access control may be why),
    an operator's runs; ctl reads user/password from --zenoh-config."""
    from hystbench.acquisition.zenoh_bus import peer_config
    from hystbench.config import CONFIG_DIR

    users = tmp_path / "users.txt"
    users.write_text("operator:op-secret\nviewer:view-secret\n", encoding="utf-8")
    users.chmod(0o600)
    acl = tmp_path / "zenoh-acl.json5"
    acl.write_text((CONFIG_DIR / "zenoh-acl.json5").read_text(encoding="utf-8")
                   .replace("/etc/hystbench/zenoh-users.txt", users.as_posix()), encoding="utf-8")
    port = free_port()
    toml = tmp_path / "acl.toml"
    toml.write_text(f'[daemon]\nbench = "t"\nlog_dir = "{tmp_path.as_posix()}"\n[source]\nkind = "sim"\n'
                    f'[recording]\nenabled = false\n[zenoh]\nconfig = "{acl.as_posix()}"\n'
                    f'listen = ["tcp/127.0.0.1:{port}"]\n', encoding="utf-8")
    clients = {}
    for user in ("viewer", "operator"):
        clients[user] = tmp_path / f"{user}.json5"
        password = {"viewer": "view-secret", "operator": "op-secret"}[user]
        clients[user].write_text(json.dumps(peer_config(connect=[f"tcp/127.0.0.1:{port}"], user=user,
                                                        password=password)), encoding="utf-8")
    svc = BenchService(load_daemon_config(toml)).start()
    try:
        code, out, err = run(["ctl", "--zenoh-config", str(clients["viewer"]), "--bench", "t", "--timeout", SAFETY,
                              "status"], capsys)
        assert code == 0 and out.startswith("t: running")  # everyone may ask
        code, out, err = run(["ctl", "--zenoh-config", str(clients["viewer"]), "--bench", "t", "--timeout", "1",
                              "output", "on"], capsys)
        assert code == 2 and "no daemon answered on hystbench/t/cmd/output" in err and "access control" in err
        assert not svc.source.rig.output_enabled  # nothing was driven
        code, out, err = run(["ctl", "--zenoh-config", str(clients["operator"]), "--bench", "t", "--timeout", SAFETY,
                              "output", "on"], capsys)
        assert code == 0 and out.startswith("t: output ok")
    finally:
        svc.stop()
