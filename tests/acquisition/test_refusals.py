"""A command the bench cannot carry out NOW is a CommandRefused, not a ConfigError: nothing in the
files or the command's arguments is wrong (issue 11).  Arguments that are wrong stay ConfigError.

A BenchService on the simulated rig with zenoh, recording and estimation off: cheap, and the
commands are called as the zenoh queryable calls them."""

from __future__ import annotations

from pathlib import Path

import pytest

from hystbench.errors import CommandRefused, ConfigError
from hystbench.service.daemon_config import load_daemon_config
from hystbench.service.service import BenchService


def bench(tmp_path: Path, kind: str = "sim") -> BenchService:
    cfg = tmp_path / "d.toml"
    cfg.write_text(f'[daemon]\nbench = "r1"\nlog_dir = "{tmp_path.as_posix()}"\n[source]\nkind = "{kind}"\n'
                   '[estimation]\nenabled = false\n[recording]\nenabled = false\n[zenoh]\nenabled = false\n',
                   encoding="utf-8")
    return BenchService(load_daemon_config(cfg))


def test_commands_before_start_and_during_a_sweep_are_refused_not_misconfigured(tmp_path):
    svc = bench(tmp_path)
    with pytest.raises(CommandRefused, match="bench is starting; try again when it is running") as before:
        svc.command("output", {"on": True})
    assert not isinstance(before.value, ConfigError)
    svc.start()
    try:
        assert svc.command("start_sweep", {"frequencies_hz": [160.0], "dwell_s": 600.0})["points"] == 1
        with pytest.raises(CommandRefused, match="start_sweep: a sweep is running; stop_sweep first") as busy:
            svc.command("start_sweep", {"frequencies_hz": [160.0], "dwell_s": 600.0})
        assert not isinstance(busy.value, ConfigError)
        # what the command asks for is still the configuration's kind of error, refused before anything runs
        with pytest.raises(ConfigError, match="dwell_s"):
            svc.command("start_sweep", {"frequencies_hz": [160.0], "dwell_s": -1.0})
        # estimation off, a point still needs one whole period of its frequency
        with pytest.raises(ConfigError, match=r"dwell_s = 0\.001 s is too short at 160 Hz, where a point needs 1 period \(to be seen whole\)"):
            svc.command("start_sweep", {"frequencies_hz": [320.0, 160.0], "dwell_s": 0.001})
        assert svc.command("stop_sweep", {}) == {"stopped": True}
    finally:
        svc.stop()


def test_a_source_that_takes_no_commands_refuses_them(tmp_path):
    svc = bench(tmp_path, kind="synthetic").start()
    try:
        with pytest.raises(CommandRefused, match="takes no commands") as err:
            svc.command("output", {"on": True})
        assert not isinstance(err.value, ConfigError)
    finally:
        svc.stop()
