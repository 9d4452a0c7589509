"""Issue 30, item 2: Ctrl-C keeps exit status 130 but says so in one line; ``record`` says that the
partial log is closed and valid, and where it is."""

from __future__ import annotations

import os
import signal
from pathlib import Path

from hystbench.cli import main as cli_main
from hystbench.cli import pipeline as cli_pipeline
from hystbench.formats.mcaplog import iter_blocks


def test_ctrl_c_in_any_command_is_said_and_exits_130(monkeypatch, capsys):
    def interrupted(args):
        raise KeyboardInterrupt

    monkeypatch.setattr(cli_main, "cmd_rigs", interrupted)  # build_parser reads it when main runs
    code = cli_main.main(["rigs"])
    err = capsys.readouterr().err
    assert code == 130
    assert err.strip().splitlines() == ["hystbench rigs: interrupted"]


def test_ctrl_c_during_record_leaves_a_closed_valid_log_and_says_where(tmp_path: Path, monkeypatch, capsys):
    sent: list[bool] = []

    def ctrl_c_at_first_estimate(topic, obj):  # the event: an estimate exists, so the log holds data
        if topic == "/estimate" and not sent:
            sent.append(True)
            os.kill(os.getpid(), signal.SIGINT)

    monkeypatch.setattr(cli_pipeline, "_print_estimate", ctrl_c_at_first_estimate)
    out = tmp_path / "run.mcap"
    handler = signal.getsignal(signal.SIGINT)
    # an hour of real time: only the interrupt ends it (a failure to interrupt is a hang, not a pass)
    code = cli_main.main(["record", "--source", "sim", "--rig", "voicecoil_ferrite", "--seconds", "3600",
                          "--freq", "320", "--out", str(out), "-v"])
    cap = capsys.readouterr()
    assert sent and code == 130, cap.err
    lines = cap.err.strip().splitlines()
    assert len(lines) == 1 and "interrupted" in lines[0] and "closed and valid" in lines[0], cap.err
    assert str(out) in lines[0]
    assert signal.getsignal(signal.SIGINT) is handler  # the handler was given back
    samples = sum(b.n for b in iter_blocks(out))  # the reader reads it to its end
    assert 0 < samples < 3600 * 100_000
    assert f"{samples} samples" in lines[0]
