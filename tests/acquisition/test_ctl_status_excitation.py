"""Issue 30, item 8: ``ctl status`` (and ``health``) say whether the output is on, and at what
frequency, current and offset, as the bench played it; against a real BenchService (simulated
rig) on a loopback zenoh endpoint, as in test_ctl.py."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from hystbench.acquisition.zenoh_bus import Subscription, free_port, load_zenoh_config, open_session
from hystbench.cli.main import main
from hystbench.formats.raw_block import decode
from hystbench.messages import OperatingPoint
from hystbench.service.daemon_config import load_daemon_config
from hystbench.service.service import BenchService

SAFETY_S = 60.0  # turns a hang into a failure; nothing waits for it on success
SAFETY = str(SAFETY_S)


@pytest.fixture
def bench(tmp_path: Path):
    port = free_port()
    cfg = tmp_path / "d.toml"
    cfg.write_text(f'[daemon]\nbench = "t1"\nlog_dir = "{tmp_path.as_posix()}"\n[source]\nkind = "sim"\n'
                   f'[recording]\nenabled = false\n[estimation]\nenabled = false\n'
                   f'[zenoh]\nlisten = ["tcp/127.0.0.1:{port}"]\n', encoding="utf-8")
    svc = BenchService(load_daemon_config(cfg)).start()
    try:
        yield svc, f"tcp/127.0.0.1:{port}"
    finally:
        svc.stop()


def ctl(ep: str, *verb: str, capsys) -> str:
    code = main(["ctl", "--connect", ep, "--bench", "t1", "--timeout", SAFETY, *verb])
    cap = capsys.readouterr()
    assert code == 0, cap.err
    return cap.out


def played(raw: Subscription, want) -> None:
    """Until two blocks in a row were played at a point ``want`` accepts: the raw block is published
    before the pipeline takes it in, so the first one's arrival is certain only once the next comes."""
    run = 0
    while run < 2:
        item = raw.get(SAFETY_S)
        assert item is not None, "no raw block at the commanded point"
        run = run + 1 if want(OperatingPoint.from_meta(decode(item[1], item[0]).meta)) else 0


def test_status_shows_the_output_and_the_excitation_as_played(bench, capsys):
    svc, ep = bench
    watcher = open_session(load_zenoh_config(None, connect=[ep]))
    raw = Subscription(watcher, "hystbench/t1/raw")
    try:
        played(raw, lambda p: not p.output_on)  # the daemon starts with the output off
        assert "; output off at " in ctl(ep, "status", capsys=capsys)

        ctl(ep, "set_excitation", "--freq", "160", "--ipp", "0.8", "--offset", "0.1", capsys=capsys)
        ctl(ep, "output", "on", capsys=capsys)
        played(raw, lambda p: p.output_on and p.frequency_hz == 160.0 and p.current_pp_a == 0.8)
        line = ctl(ep, "status", capsys=capsys)
        assert line.startswith("t1: running; output on at 160 Hz, 0.8 A-pp, offset 0.1 A; source "), line

        health = json.loads(ctl(ep, "health", "--json", capsys=capsys))
        assert health["output_on"] is True and health["as_of"] == "played"
        assert (health["frequency_hz"], health["current_pp_a"], health["offset_a"]) == (160.0, 0.8, 0.1)
        text = ctl(ep, "health", capsys=capsys).splitlines()
        assert "output_on: True" in text and "frequency_hz: 160.0" in text and "offset_a: 0.1" in text
    finally:
        raw.close()
        watcher.close()
