"""Issue 16 item 3: an idle daemon (output off) no longer records ~380 kB/s of raw samples, and its
logs are bounded by retention (age, total size), oldest parts first, never the open one.

Expected sample counts are arithmetic on the decimation's definition (the first 10 ms of every
second of sample time), not the recorder's output."""

from __future__ import annotations

import os
import time
from pathlib import Path

import numpy as np
import pytest

from hystbench.acquisition.sources import operating_meta
from hystbench.blocks import SampleBlock
from hystbench.formats.mcaplog import STATUS, iter_blocks, iter_log
from hystbench.formats.mcaplog.recorder import McapRecorder
from hystbench.service.daemon_config import load_daemon_config
from hystbench.service.retention import apply_retention
from hystbench.service.service import BenchService

FS = 100_000.0


def _blocks(seconds: float, on_from: float | None = None, n: int = 1000):
    """``seconds`` of 1000-sample blocks, output off (on from ``on_from`` s if given)."""
    for k in range(int(seconds * FS) // n):
        on = on_from is not None and k * n >= on_from * FS
        x = np.full(n, float(k), dtype=np.float32)
        yield SampleBlock(k * n, FS, {"current_A": x, "force_N": x}, meta=operating_meta(320.0, 1.4, 0.0, on))


@pytest.mark.parametrize("policy, expected", [
    ("full", 3 * 100_000 + 100_000),
    ("decimated", 3 * 1_000 + 100_000),  # 10 ms (1000 samples) in each of the 3 idle seconds, then all
    ("off", 100_000),
])
def test_idle_raw_keeps_what_the_policy_says(tmp_path: Path, policy: str, expected: int) -> None:
    path = tmp_path / f"{policy}.mcap"
    with McapRecorder(path, idle_raw=policy) as rec:
        for b in _blocks(4.0, on_from=3.0):
            rec.add_block(b)
    got = list(iter_blocks(path))
    assert sum(b.n for b in got) == expected
    idle = [b for b in got if not b.meta["output_on"]]
    if policy == "decimated":  # each snapshot starts on a whole second of sample time
        assert [b.first_index for b in idle] == [0, 100_000, 200_000]
    assert rec.idle_samples_skipped == 3 * 100_000 + 100_000 - expected


def test_decimation_cuts_blocks_that_straddle_a_snapshot(tmp_path: Path) -> None:
    path = tmp_path / "odd.mcap"
    with McapRecorder(path, idle_raw="decimated") as rec:  # 3 s in 70 000-sample reads (what a lagging ring gives)
        for b in _blocks(2.8, n=70_000):
            rec.add_block(b)
    got = list(iter_blocks(path))
    assert [(b.first_index, b.n) for b in got] == [(0, 1000), (100_000, 1000), (200_000, 1000)]


def _touch(path: Path, size: int, age_days: float, finished: bool = True) -> Path:
    body = b"\x89MCAP0\r\n" + b"x" * max(0, size - 16) + (b"\x89MCAP0\r\n" if finished else b"y" * 8)
    path.write_bytes(body)
    t = time.time() - age_days * 86_400
    os.utime(path, (t, t))
    return path


def test_retention_deletes_oldest_first_and_never_the_open_part(tmp_path: Path) -> None:
    old = _touch(tmp_path / "b1-20240101-000000-0001.mcap", 1000, 40)
    mid = _touch(tmp_path / "b1-20240201-000000-0001.mcap", 1000, 20)
    new = _touch(tmp_path / "b1-20240301-000000.2-0002.mcap", 1000, 1)
    open_part = _touch(tmp_path / "b1-20240301-000000-0003.mcap", 5000, 100)  # ours, being written: spared
    other = _touch(tmp_path / "b2-20240101-000000-0001.mcap", 1000, 90)  # another bench's
    export = _touch(tmp_path / "b1-20240101-000000-0001.recovered.mcap", 1000, 90)  # not a log part
    rep = apply_retention(tmp_path, "b1", keep_days=30, keep=[open_part])
    assert rep.deleted == [old] and rep.deleted_bytes == 1000
    rep = apply_retention(tmp_path, "b1", max_total_bytes=6500, keep=[open_part])  # 5000 + 2 x 1000 > 6500
    assert rep.deleted == [mid] and rep.kept == 2
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(p.name for p in (new, open_part, other, export))


def test_retention_spares_a_fresh_unfinished_part_another_process_may_write(tmp_path: Path) -> None:
    busy = _touch(tmp_path / "b1-20240101-000000-0001.mcap", 1000, 0, finished=False)
    crashed = _touch(tmp_path / "b1-20230101-000000-0001.mcap", 1000, 400, finished=False)
    rep = apply_retention(tmp_path, "b1", keep_days=1, max_total_bytes=1)
    assert rep.deleted == [crashed] and busy.exists()


def test_the_service_applies_retention_and_says_so(tmp_path: Path) -> None:
    """Tiny limits: an old log part of this bench goes at start-up, and a status message says so."""
    old = _touch(tmp_path / "r-20200101-000000-0001.mcap", 4096, 10)
    toml = tmp_path / "d.toml"
    toml.write_text(f'[daemon]\nbench = "r"\nlog_dir = "{tmp_path.as_posix()}"\n[source]\nkind = "sim"\n'
                    '[zenoh]\nenabled = false\n[estimation]\nenabled = false\n'
                    '[recording]\nkeep_days = 1.0\nmax_total_gib = 1e-3\n', encoding="utf-8")
    svc = BenchService(load_daemon_config(toml)).start()
    try:
        assert not old.exists() and svc.health()["retention_deleted"] == 1
        assert svc.recorder.paths[-1].exists()  # the open part
    finally:
        paths = svc.stop()
    events = [m.json() for m in iter_log(paths[0], [STATUS])]
    ret = [e for e in events if e["event"] == "retention"]
    assert ret and ret[0]["deleted"] == [old.name] and ret[0]["deleted_bytes"] == 4096
    assert any(e["event"] == "log" and e["log_dir"] == str(tmp_path) for e in events)
