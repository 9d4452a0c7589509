"""Issue 26 item 3: a log folder that refuses writes pauses the log, not the bench service.

The disk is real: a tmpfs of a few MiB mounted for the test (root only; skipped, saying why,
elsewhere), filled by the daemon's own log.  Then: the output goes off, ``status`` and ``health``
name the folder and its free space, zenoh still answers, ``output on`` is refused, and once room
is back the log resumes by itself in a new part.  SIGTERM ends the daemon in that state and frees
the bench's lock.  Retention keeps ``max_total_gib`` as the log grows, not once a minute."""

from __future__ import annotations

import contextlib
import json
import signal
import subprocess
from pathlib import Path
from typing import Any, Iterator

import pytest

from hystbench.acquisition.zenoh_bus import (Subscription, free_port, load_zenoh_config, open_session, peer_config,
                                             send_command)
from hystbench.errors import CommandRefused, LogWriteError
from hystbench.formats.mcaplog import McapRecorder
from hystbench.formats.raw_block import decode
from hystbench.messages import OperatingPoint
from hystbench.service.daemon_config import load_daemon_config
from hystbench.service.retention import bench_logs
from hystbench.service.service import BenchService
from hystbench.service.service_log import RESUME_FREE_BYTES

from .conftest import HANG_S, Daemon, health_when

pytestmark = pytest.mark.slow(30)  # ~30 s: handed to a worker before lighter files (tests/conftest.py)


@pytest.fixture
def small_disk(tmp_path: Path):
    """A tmpfs of ``size_mib`` mounted in the test's folder, unmounted after it."""
    mounted: list[Path] = []

    def make(size_mib: int) -> Path:
        where = tmp_path / f"disk{len(mounted)}"
        where.mkdir()
        done = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size_mib}m", "tmpfs", str(where)],
                              capture_output=True, text=True)
        if done.returncode:
            pytest.skip(f"a small disk needs mount -t tmpfs (root): {done.stderr.strip()}")
        mounted.append(where)
        return where

    yield make
    for where in mounted:
        subprocess.run(["umount", "-l", str(where)], check=False)


def fill(disk: Path, leave_bytes: int) -> Path:
    """A file taking all but ``leave_bytes`` of ``disk``."""
    import shutil

    filler = disk / "filler.bin"
    with open(filler, "wb") as fh:
        fh.truncate(0)
        left = shutil.disk_usage(disk).free - leave_bytes
        chunk = b"\0" * 2**20
        while left > 0:
            fh.write(chunk[:left])
            left -= len(chunk)
    return filler


def logging_daemon(tmp_path: Path, bench: str, logs: Path) -> tuple[Daemon, int]:
    """A daemon on the simulated rig logging every raw sample to ``logs`` (flushed every 0.25 s, no
    cap), and the loopback port it listens on."""
    port, cfg = free_port(), tmp_path / "daemon.toml"
    cfg.write_text(f'[daemon]\nbench = "{bench}"\nlog_dir = "{logs.as_posix()}"\nstop_timeout_s = {HANG_S}\n[source]\n'
                   'kind = "sim"\n[recording]\nidle_raw = "full"\nflush_interval_s = 0.25\nmax_total_gib = 0.0\n'
                   f'[zenoh]\nlisten = ["tcp/127.0.0.1:{port}"]\n', encoding="utf-8")
    return Daemon(tmp_path, cfg), port


@contextlib.contextmanager
def watched(d: Daemon, port: int, bench: str) -> Iterator[tuple[Any, Subscription, Subscription]]:
    """The daemon ready, a session to it with its ``status`` and ``raw`` subscriptions; all closed after."""
    session = None
    try:
        d.wait_for("READY=1")
        session = open_session(load_zenoh_config(peer_config(connect=[f"tcp/127.0.0.1:{port}"])))
        yield session, Subscription(session, f"hystbench/{bench}/status"), Subscription(session, f"hystbench/{bench}/raw")
    finally:
        if session is not None:
            session.close()
        d.close()


def events_until(status: Subscription, last: str) -> dict:
    """The status events received up to ``last`` (by event name)."""
    events: dict = {}
    while last not in events:
        got = status.get(HANG_S)
        assert got is not None, f"no {last} status; got {list(events)}"
        events[json.loads(got[1])["event"]] = json.loads(got[1])
    return events


def raw_until(raw: Subscription, output_on: bool, after: str) -> None:
    """Raw blocks received until one with the output ``output_on`` (a block that shows it)."""
    while True:
        got = raw.get(HANG_S)
        assert got is not None, f"no raw block with the output {'on' if output_on else 'off'} {after}"
        if OperatingPoint.from_meta(decode(got[1]).meta).output_on == output_on:
            return


def test_a_full_disk_pauses_the_log_output_off_and_it_resumes_by_itself(tmp_path: Path, small_disk) -> None:
    disk = small_disk(16)
    logs = disk / "logs"
    filler = fill(disk, 3 * 2**20)  # 3 MiB left: the log fills it in a couple of seconds
    d, port = logging_daemon(tmp_path, "full", logs)
    with watched(d, port, "full") as (session, status, raw):
        health_when(session, "full", lambda h: True)  # connected: the subscriptions see what follows
        send_command(session, "full", "output", {"on": True}, timeout_s=30.0)
        paused = health_when(session, "full", lambda h: h["logging"] == "paused")
        assert "No space left on device" in paused["log_error"] and str(logs) in paused["log_error"]
        assert "MiB free" in paused["log_error"] and paused["log_free_bytes"] < RESUME_FREE_BYTES
        assert paused["state"] == "running" and d.proc.poll() is None  # zenoh still answers
        events = events_until(status, "logging_paused")
        assert events["log_write_failed"]["folder"] == str(logs) and "output off" in events["logging_paused"]["message"]
        raw_until(raw, False, "after the log failed")
        with pytest.raises(CommandRefused, match=r"log cannot be written .*No space left on device.*resumes by itself"):
            send_command(session, "full", "output", {"on": True}, timeout_s=30.0)
        filler.unlink()  # room again
        resumed = health_when(session, "full", lambda h: h["logging"] == "on")
        assert resumed["log"] and Path(resumed["log"]).exists() and resumed["log_error"] is None
        assert send_command(session, "full", "output", {"on": True}, timeout_s=30.0)["ok"]
        d.proc.send_signal(signal.SIGTERM)  # bounded by stop_timeout_s = HANG_S: on a busy machine closing a log
        assert d.proc.wait(timeout=2 * HANG_S) == 0, d.stderr()[-2000:]  # on a full disk outlasted the 4.5 s default
    parts = bench_logs(logs, "full")
    assert len(parts) == 2 and all(p.stat().st_size > 0 for p in parts)  # the cut part and the resumed one


def test_a_log_folder_removed_while_running_pauses_the_log_with_the_output_off(tmp_path: Path) -> None:
    """``rm -rf`` of the log folder: the daemon wrote on into the deleted part for as long as it ran,
    said ``logging: on`` and, at stop, "log <a path that is gone>": everything from then on was lost
    without a word.  Now the next flush finds the open part deleted: the log is paused with the output
    off, the status names the part, and logging resumes in a new part (the folder made again), the
    output still off until asked."""
    import shutil

    logs = tmp_path / "logs"
    d, port = logging_daemon(tmp_path, "gone", logs)
    with watched(d, port, "gone") as (session, status, raw):
        health_when(session, "gone", lambda h: h["logging"] == "on" and h["log"])
        send_command(session, "gone", "output", {"on": True}, timeout_s=30.0)
        raw_until(raw, True, "after output on")  # on first: what follows shows it going off
        shutil.rmtree(logs)
        events = events_until(status, "log_resumed")
        assert "logging_paused" in events and "output off" in events["logging_paused"]["message"]
        failed = events["log_write_failed"]["message"]
        # the part open when the folder went (not necessarily the first: a fault on a starved machine
        # rotates the log, as it should)
        assert "was deleted" in failed and f"{logs}/gone" in failed, failed
        raw_until(raw, False, "after the log was deleted")
        resumed = health_when(session, "gone", lambda h: h["logging"] == "on")
        assert Path(resumed["log"]).exists() and d.proc.poll() is None  # a new part, in the folder made again
        d.proc.send_signal(signal.SIGTERM)
        assert d.proc.wait(timeout=2 * HANG_S) == 0, d.stderr()[-2000:]


def test_sigterm_on_a_full_disk_ends_the_daemon_and_frees_the_bench(tmp_path: Path, small_disk) -> None:
    """Started on a folder with no room: the daemon serves (log paused, output refused), a restart
    leaves no empty part, SIGTERM ends it with exit 0 and the bench's lock is free again."""
    disk = small_disk(4)
    logs = disk / "logs"
    logs.mkdir()
    fill(disk, 0)
    port, cfg = free_port(), tmp_path / "daemon.toml"
    cfg.write_text(f'[daemon]\nbench = "nofree"\nlog_dir = "{logs.as_posix()}"\nstop_timeout_s = {HANG_S}\n[source]\nkind = "sim"\n'
                   f'[zenoh]\nlisten = ["tcp/127.0.0.1:{port}"]\n', encoding="utf-8")
    for run in range(2):
        d = Daemon(tmp_path, cfg, name=str(run))
        session = None
        try:
            d.wait_for("READY=1")
            session = open_session(load_zenoh_config(peer_config(connect=[f"tcp/127.0.0.1:{port}"])))
            h = health_when(session, "nofree", lambda h: h["logging"] == "paused")
            assert "No space left on device" in h["log_error"] and h["output_refused"]
            d.proc.send_signal(signal.SIGTERM)
            assert d.proc.wait(timeout=2 * HANG_S) == 0, d.stderr()[-2000:]
        finally:
            if session is not None:
                session.close()
            d.close()
        assert not list(logs.glob("*.mcap"))  # no empty part left behind, run after run


# --- in the process: the recorder and retention ---------------------------------------------------------
def test_a_write_error_names_the_part_the_folder_and_its_free_space(small_disk) -> None:
    disk = small_disk(2)
    rec = McapRecorder(disk / "x.mcap", compression="none", chunk_size=64 * 1024, flush_interval_s=0.01).start()
    with pytest.raises(LogWriteError) as info:
        for _ in range(10_000):  # 640 MB at most; the 2 MiB disk is full long before
            rec.add_message("/status", {"t_ns": 0, "level": "info", "event": "fill", "message": "x" * 65_536})
    err = info.value
    assert str(disk / "x.mcap") in str(err) and "No space left on device" in str(err) and "MiB free" in str(err)
    assert err.folder == str(disk) and err.errno == 28
    rec.abandon()
    with pytest.raises(LogWriteError, match="cannot start the log: No space left"):
        McapRecorder(disk / "y.mcap").start()
    assert not (disk / "y.mcap").exists()  # no empty part


def test_record_on_a_full_disk_fails_saying_how_far_the_log_got(small_disk, capsys) -> None:
    """``hystbench record`` whose log stops at a full disk is not a success (it said "wrote ..." and
    exit 0): status 2, the samples the log holds against those recorded, and how to salvage it."""
    from hystbench.cli.main import main

    disk = small_disk(1)
    fill(disk, 300_000)
    code = main(["record", "--source", "sim", "--seconds", "2", "--pace", "max", "--out", str(disk / "r.mcap")])
    err = capsys.readouterr().err
    assert code == 2 and "wrote" not in err
    line = next(ln for ln in err.splitlines() if "the log stopped" in ln)
    assert f"{disk / 'r.mcap'}: the log stopped after" in line and "of 200000 samples" in line
    assert "No space left on device" in line and f"hystbench recover {disk / 'r.mcap'}" in line


def test_retention_keeps_the_cap_as_the_log_grows(tmp_path: Path) -> None:
    """A 2 MiB cap and a log written as fast as the simulation runs: at every point where the
    recorder tells its size, this bench's parts add up to no more than the cap."""
    cap = 2 * 2**20
    toml = tmp_path / "daemon.toml"
    toml.write_text(f'[daemon]\nbench = "cap"\nlog_dir = "{tmp_path.as_posix()}"\n'
                    '[source]\nkind = "sim"\npace = "max"\nblock_samples = 5000\n'
                    f'[recording]\nidle_raw = "full"\ncompression = "none"\nchunk_kib = 64\n'
                    f'max_total_gib = {cap / 2**30!r}\n[zenoh]\nenabled = false\n[estimation]\nenabled = false\n',
                    encoding="utf-8")
    svc = BenchService(load_daemon_config(toml))
    totals: list[int] = []
    told = svc.log._grew

    def grew(part: Path, size: int) -> None:
        told(part, size)
        totals.append(sum(p.stat().st_size for p in bench_logs(tmp_path, "cap")))
    svc.log._grew = grew
    svc.start()
    try:
        svc.pipeline.after_samples(1_500_000).wait(HANG_S)  # 24 MB of samples: 11 times the cap
    finally:
        svc.stop()
    assert len(totals) > 100 and svc.log.deleted > 5
    assert max(totals) <= cap, f"the folder reached {max(totals) / 2**20:.2f} MiB against a 2 MiB cap"


#: ``hystbench daemon`` whose service never finishes stopping (a hung driver, a log on a dead disk): the
#: stop waits on an event nobody sets
HUNG_STOP = """
import sys, threading
import hystbench.service.service as service
service.BenchService.stop = lambda self, timeout_s=3.0: threading.Event().wait()
from hystbench.cli.main import main
sys.exit(main(sys.argv[1:]))
"""


def test_a_stop_past_stop_timeout_s_ends_the_process_at_once_saying_so(tmp_path: Path) -> None:
    """[daemon] stop_timeout_s bounds SIGTERM's stop: past it the process ends at once, exit 1, naming
    the key.  The stop is made to hang (it had been a real stop against a bound of 1 ms, which a stop
    beside two busy loops once beat: exit 0)."""
    port, cfg = free_port(), tmp_path / "daemon.toml"
    cfg.write_text(f'[daemon]\nbench = "quick"\nstop_timeout_s = 0.2\n[source]\nkind = "sim"\n'
                   f'[zenoh]\nlisten = ["tcp/127.0.0.1:{port}"]\n', encoding="utf-8")
    d = Daemon(tmp_path, cfg, python=("-c", HUNG_STOP))
    try:
        d.wait_for("READY=1")
        d.proc.send_signal(signal.SIGTERM)
        assert d.proc.wait(timeout=HANG_S) == 1
        assert "did not stop within 0.2 s ([daemon] stop_timeout_s)" in d.stderr()
    finally:
        d.close()
