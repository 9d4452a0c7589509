"""Issue 16 item 1: a fault in a stage switches the output off, is published and logged, and the
service starts its source and pipeline again (output off, a new log part) and takes commands.

The fault is a real one: the emulated current amplifier latches INTERLOCK (as the hardware would
when its interlock opens); the drivers' heartbeat sees it, switch the output off and the source
raises in the pipeline's source thread."""

from __future__ import annotations

import json
import threading
import time
from pathlib import Path

import pytest

from hystbench.acquisition.zenoh_bus import (Subscription, free_port, load_zenoh_config, open_session, peer_config,
                                             send_command)
from hystbench.errors import BenchError
from hystbench.formats.mcaplog import STATUS, iter_log
from hystbench.service.daemon_config import load_daemon_config
from hystbench.service.service import BenchService
from hystbench.service.service import MAX_FAULTS, TooManyFaults


def test_a_fault_restarts_the_source_output_off_in_a_new_log_part(tmp_path: Path) -> None:
    port = free_port()
    toml = tmp_path / "daemon.toml"
    toml.write_text(f'[daemon]\nbench = "f"\nlog_dir = "{tmp_path.as_posix()}"\n[source]\nkind = "bench"\n'
                    f'[zenoh]\nlisten = ["tcp/127.0.0.1:{port}"]\n', encoding="utf-8")
    svc = BenchService(load_daemon_config(toml)).start()
    client = open_session(load_zenoh_config(peer_config(connect=[f"tcp/127.0.0.1:{port}"])))
    status = Subscription(client, "hystbench/f/status")
    try:
        on = threading.Event()
        svc.pipeline.listeners.append(lambda t, o: on.set() if t == "/estimate" else None)
        send_command(client, "f", "output", {"on": True}, timeout_s=30.0)
        assert on.wait(30.0)  # driven: estimates come only with the output on
        first_source, first_part = svc.source, svc.recorder.paths[-1]
        first_source.emu.amplifier.trip("INTERLOCK")
        assert svc.pipeline.join(30.0)  # every stage ended: the source thread raised
        assert svc.pipeline.error is not None and "INTERLOCK" in str(svc.pipeline.error)
        assert svc.recover()
        assert not first_source.emu.rig.output_enabled  # the old bench: off
        assert svc.source is not first_source and svc.state == "running"
        assert svc.recorder.paths[-1] != first_part and len(svc.recorder.paths) == 2
        new_rig = svc.source.emu.rig
        assert not new_rig.output_enabled  # the new bench starts with the output off
        events = {}
        for _ in range(200):  # the published events, in order; bounded
            got = status.get(10.0)
            assert got is not None, f"no 'restarted' status; got {list(events)}"
            msg = json.loads(got[1])
            events[msg["event"]] = msg
            if msg["event"] == "restarted":
                break
        assert "INTERLOCK" in events["fault"]["message"] and events["fault"]["level"] == "error"
        assert "output off" in events["restarted"]["message"]
        assert send_command(client, "f", "set_excitation", {"frequency_hz": 160.0}, timeout_s=30.0)["ok"]
        health = send_command(client, "f", "output", {"on": False}, timeout_s=30.0)
        assert health["ok"] and svc.health()["faults"] == 1 and "INTERLOCK" in svc.health()["last_fault"]
    finally:
        status.close()
        client.close()
        paths = svc.stop()
    assert len(paths) == 2
    old = [m.json() for m in iter_log(paths[0], [STATUS])]
    assert old[-1]["event"] == "fault" and "INTERLOCK" in old[-1]["message"]  # the fault closes the old part
    new = [m.json()["event"] for m in iter_log(paths[1], [STATUS])]
    assert "restarted" in new and new[-1] == "stopping"


def test_faults_in_quick_succession_stop_the_service_with_too_many_faults(tmp_path: Path) -> None:
    """The sixth fault within FAULT_WINDOW_S is not restarted from: recover raises TooManyFaults
    (the service's verdict, not a bare BenchError), the amplifier's fault its cause, the output off.
    The five earlier faults are entered as the service counted them (a real sixth one follows)."""
    toml = tmp_path / "daemon.toml"
    toml.write_text(f'[daemon]\nbench = "g"\nlog_dir = "{tmp_path.as_posix()}"\n[source]\nkind = "bench"\n'
                    f'[zenoh]\nenabled = false\n', encoding="utf-8")
    svc = BenchService(load_daemon_config(toml)).start()
    try:
        on = threading.Event()
        svc.pipeline.listeners.append(lambda t, o: on.set() if t == "/estimate" else None)
        svc.command("output", {"on": True})
        assert on.wait(30.0)
        now = time.monotonic()
        svc.faults.extend((now, f"earlier fault {k}") for k in range(MAX_FAULTS))
        source = svc.source
        source.emu.amplifier.trip("INTERLOCK")
        assert svc.pipeline.join(30.0)
        with pytest.raises(TooManyFaults, match=rf"{MAX_FAULTS + 1} faults within .* giving up; the last: .*INTERLOCK") \
                as info:
            svc.recover()
        assert info.value.__cause__ is svc.pipeline.error and isinstance(info.value, BenchError)
        assert not source.emu.rig.output_enabled and svc.source is source  # output off; no restart
    finally:
        svc.stop()


def test_an_emulated_rig_that_fails_is_named_as_the_cause_and_counts_as_a_fault(tmp_path: Path, monkeypatch) -> None:
    """The emulated rig refuses a block (the clock trips the amplifier's INTERLOCK and runs on):
    the pipeline's error is a SimulationError naming the rig's own cause, not only the interlock it
    tripped, and recover() counts it as a fault the service cannot control (not a trip)."""
    import numpy as np

    from hystbench.errors import SimulationError

    toml = tmp_path / "daemon.toml"
    toml.write_text(f'[daemon]\nbench = "r"\nlog_dir = "{tmp_path.as_posix()}"\n[source]\nkind = "bench"\n'
                    '[zenoh]\nenabled = false\n[estimation]\nenabled = false\n', encoding="utf-8")
    svc = BenchService(load_daemon_config(toml)).start()
    try:
        actuator = svc.source.emu.rig.actuator
        real, cause = actuator.step, "the iron's field did not converge (injected)"

        def refuse_with_current(t_s, current_a, dcurrent_dt):
            if np.any(current_a != 0.0):
                raise SimulationError(cause)
            return real(t_s, current_a, dcurrent_dt)

        monkeypatch.setattr(actuator, "step", refuse_with_current)
        svc.command("output", {"on": True})
        assert svc.pipeline.join(30.0)
        err = svc.pipeline.error
        assert isinstance(err, SimulationError) and cause in str(err) and "INTERLOCK" in str(err)
        assert svc.recover() and svc.health()["faults"] == 1 and svc.trips == 0
    finally:
        svc.stop()


@pytest.mark.parametrize("factory, says", [
    ("os:sep", "str '/' is not callable"),
    ("json:loads", "calling it raised TypeError"),
])
def test_a_compensator_factory_that_is_no_function_or_fails_is_refused_by_key(tmp_path: Path, factory, says) -> None:
    """A factory that is not callable, or whose call raises, was a TypeError traceback at the start
    (and, on a reload, ended the daemon): it is the configuration's error, said by key."""
    from hystbench.errors import ConfigError

    toml = tmp_path / "d.toml"
    toml.write_text(f'[daemon]\nbench = "cf"\n[source]\nkind = "sim"\n[recording]\nenabled = false\n'
                    f'[zenoh]\nenabled = false\n[compensator]\nenabled = true\nfactory = "{factory}"\n', encoding="utf-8")
    with pytest.raises(ConfigError, match=rf"\[compensator\] factory '{factory}': .*{says}"):
        BenchService(load_daemon_config(toml)).start()
