"""Recording a bench on another PC through the router (issue 31: a live log to diagnose, wherever the
bench is): ``ZenohSource`` subscribes to the bench's raw blocks through a real router, a real daemon
(subprocess, simulated rig, sweeping) publishing them; the log it records holds exactly the samples
the daemon published, in order, with the daemon's own recording metadata; ``replay`` estimates from
it and ``export`` writes the recordings of its rig that ``diagnose`` takes.  A bench nobody serves is one clear error naming it.
Every wait ends on its event; HANG_S only turns a hang into a failure."""

from __future__ import annotations

import json
import threading
from pathlib import Path

import numpy as np
import pytest

from hystbench.acquisition.record import record_log, replay_log
from hystbench.acquisition.zenoh_bus import Subscription, free_port
from hystbench.acquisition.zenoh_source import ZenohSource
from hystbench.cli.main import main
from hystbench.errors import NetworkError, RecordingError
from hystbench.formats.mcaplog import log_metadata
from hystbench.formats.mcaplog.reader import iter_blocks
from hystbench.formats.raw_block import decode
from hystbench.service.control import client_config
from hystbench.service.router import Router

from .conftest import HANG_S, Daemon
from .test_fleet import daemon_file

pytestmark = pytest.mark.slow(15)  # ~15 s: handed to a worker before lighter files (tests/conftest.py)


def test_a_bench_is_recorded_through_the_router_sample_for_sample(tmp_path: Path) -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    with Router([endpoint]) as router:
        published = Subscription(router.session, "hystbench/r1/raw")  # what the daemon put, as the router saw it
        daemon = Daemon(tmp_path, daemon_file(tmp_path / "r1.toml", "r1", endpoint, tmp_path / "logs"), name="r1")
        try:
            daemon.wait_for("READY=1")
            src = ZenohSource("r1", client_config([endpoint]), duration_s=0.5, timeout_s=HANG_S, stall_timeout_s=HANG_S)
            try:
                summary = record_log(src, tmp_path / "remote.mcap")
            finally:
                src.close()
            # the same as a user types it, on the analyst's PC
            assert main(["record", "--source", "zenoh", "--bench", "r1", "--connect", endpoint, "--seconds", "0.2",
                         "--out", str(tmp_path / "cli.mcap")]) == 0
            assert log_metadata(tmp_path / "cli.mcap")["recording"]["rig"] == "ecore_pm"
            assert sum(b.n for b in iter_blocks(tmp_path / "cli.mcap")) >= 20_000
        finally:
            daemon.close()
        seen = {}
        while (item := published.get(0.0)) is not None:
            b = decode(item[1])
            seen[b.first_index] = b
    kept = list(iter_blocks(tmp_path / "remote.mcap"))
    assert kept and summary["samples"] == sum(b.n for b in kept) >= 50_000  # 0.5 s at 100 kHz
    for prev, b in zip(kept, kept[1:]):  # in order; a loss would be a flagged gap, never a silent one
        assert b.first_index == prev.end_index + b.gap_samples
    assert src.lost_samples == sum(b.gap_samples for b in kept)
    for b in kept:
        if b.first_index in seen:  # what the router also saw: the same samples, bit for bit
            for name, x in b.channels.items():
                np.testing.assert_array_equal(x, seen[b.first_index].channels[name].astype(x.dtype))
    assert sum(b.first_index in seen for b in kept) >= len(kept) // 2
    meta = log_metadata(tmp_path / "remote.mcap")["recording"]
    assert meta["rig"] == "ecore_pm" and meta["sample_rate_Hz"] == 100_000.0 and meta["source"] == "zenoh hystbench/r1/raw"
    assert main(["export", str(tmp_path / "remote.mcap"), "--out", str(tmp_path / "export")]) == 0
    (sidecar,) = [p for p in (tmp_path / "export").glob("*.json") if json.loads(p.read_text()).get("output_on") is not False]
    assert json.loads(sidecar.read_text())["rig"] == "ecore_pm"  # a recording `diagnose` takes, of the right rig
    fitted = [e["frequency_hz"] for e in replay_log(tmp_path / "remote.mcap") if not e.get("error")]
    assert fitted and fitted == pytest.approx([320.0] * len(fitted), rel=1e-4)  # the daemon's sweep point


def test_a_bench_nobody_serves_is_named(tmp_path: Path) -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    with Router([endpoint]):
        with pytest.raises(NetworkError, match="bench 'nobody': no daemon answered hystbench/nobody/health"):
            ZenohSource("nobody", client_config([endpoint]), timeout_s=0.5)


def test_a_daemon_that_stops_ends_the_log_closed_with_what_came(tmp_path: Path) -> None:
    """The daemon goes away mid-recording: after ``stall_timeout_s`` without a block the recording
    fails naming the bench and the key, and the log is closed and valid with every block that came."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    with Router([endpoint]):
        daemon = Daemon(tmp_path, daemon_file(tmp_path / "r2.toml", "r2", endpoint, tmp_path / "logs"), name="r2")
        try:
            daemon.wait_for("READY=1")
            src = ZenohSource("r2", client_config([endpoint]), timeout_s=HANG_S, stall_timeout_s=1.0)
            estimated = threading.Event()
            failure: list[BaseException] = []
            windows: list[tuple[int, int]] = []

            def on_message(topic: str, obj: dict) -> None:
                if topic == "/estimate" and not obj.get("error"):
                    windows.append((obj["first_index"], obj["end_index"]))
                    estimated.set()

            def record() -> None:
                try:
                    record_log(src, tmp_path / "cut.mcap", on_message=on_message)
                except BaseException as err:  # what the recording says, for the test to read
                    failure.append(err)

            worker = threading.Thread(target=record)
            worker.start()
            assert estimated.wait(HANG_S), "no estimate from the recorded blocks"
        finally:
            daemon.close()  # the bench goes away mid-recording
        worker.join(HANG_S)
        src.close()
    assert not worker.is_alive()
    assert len(failure) == 1 and isinstance(failure[0], RecordingError), failure
    said = str(failure[0]) + str(failure[0].__cause__)
    assert "bench 'r2'" in said and "hystbench/r2/raw" in said, said
    kept = list(iter_blocks(tmp_path / "cut.mcap"))  # the reference reader opens it: closed and valid
    first, end = windows[0]  # at least the samples of the estimates that came
    assert kept[0].first_index <= first and kept[-1].end_index >= end


def test_a_gap_is_the_whole_jump_and_only_what_zenoh_lost_is_counted_lost() -> None:
    """The blocks' own indices decide: a block zenoh dropped leaves a jump, flagged GAP on the next
    block and counted lost; a gap the daemon's block already flags is the same jump, not lost twice.
    (The blocks are fed to the source's reading loop directly: what a subscription would hand it.)"""
    from hystbench.blocks import BlockFlags, SampleBlock
    from hystbench.formats.raw_block import encode_binary

    def raw(first: int, gap: int = 0) -> tuple[str, bytes, int]:
        b = SampleBlock(first, 1000.0, {"current_A": np.zeros(100)}, flags=BlockFlags.GAP if gap else BlockFlags.NONE,
                        gap_samples=gap)
        return "hystbench/g/raw", encode_binary(b), 0

    class Fed:  # the Subscription's get(): these items, then nothing
        def __init__(self, items):
            self.items = list(items)

        def get(self, timeout_s):
            return self.items.pop(0) if self.items else None

    src = object.__new__(ZenohSource)
    src.bench, src.raw_key, src.duration_s, src.fs_hz = "g", "hystbench/g/raw", 0.5, 1000.0
    src.stall_timeout_s, src.lost_samples = HANG_S, 0
    # 0..100, [zenoh drops 100..200], 200..300, the daemon's own gap of 50, 350..450, then 450..550
    src._sub = Fed([raw(0), raw(200), raw(350, gap=50), raw(450)])
    got = list(src.blocks())
    assert [(b.first_index, b.gap_samples, bool(b.flags & BlockFlags.GAP)) for b in got] == [
        (0, 0, False), (200, 100, True), (350, 50, True), (450, 0, False)]
    assert src.lost_samples == 100  # the daemon's own 50 are its, not the way's
