"""Issue 30, item 9: ``watch --seconds S`` that received nothing is a failure (exit 1), said in one
line naming the key expression it listened on."""

from __future__ import annotations

from hystbench.acquisition.zenoh_bus import free_port
from hystbench.cli.main import main


def test_watch_that_received_nothing_exits_1_naming_its_key_expression(capsys):
    ep = f"tcp/127.0.0.1:{free_port()}"  # nobody publishes there
    code = main(["watch", "hystbench/nobody/estimate", "--connect", ep, "--quiet-after", "0", "--seconds", "0.3"])
    cap = capsys.readouterr()
    assert code == 1 and cap.out == ""
    lines = cap.err.strip().splitlines()
    assert len(lines) == 1, cap.err
    assert lines[0].startswith("hystbench watch: nothing received on hystbench/nobody/estimate "), lines[0]
    assert ep in lines[0] and "0.3 s" in lines[0]
