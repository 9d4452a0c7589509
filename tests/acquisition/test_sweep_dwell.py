"""Issue 16: a daemon sweep dwells on the source's own sample clock, not on wall time.

Each point lasts ``dwell_s * fs`` samples from its command, however fast or slow the source runs
against the wall clock (an emulated bench on a busy machine runs slower than real time; a
``pace = "max"`` simulation runs faster).  The source here is the simulated rig paced ``max``:
it runs as fast as the pipeline takes its samples, far from the wall clock, so a wall-clock
dwell gives each point a number of samples that has nothing to do with ``dwell_s * fs``.  A
source that ends or stalls mid-dwell ends the sweep with an error, never with ``sweep_done``."""

from __future__ import annotations

import threading
from collections import Counter
from pathlib import Path

from hystbench.formats.mcaplog import iter_blocks
from hystbench.service import service
from hystbench.service.daemon_config import load_daemon_config
from hystbench.service.service import BenchService

HANG_S = 120.0  # a safety timeout: waits end on their event, only a hang takes this long
FS = 100_000.0
BLOCK = 1000
FREQS = (160.0, 320.0)
DWELL_S = 0.5


def make_service(tmp: Path) -> BenchService:
    toml = tmp / "daemon.toml"
    toml.write_text(f'[daemon]\nbench = "dw"\nlog_dir = "{tmp.as_posix()}"\n'
                    f'[source]\nkind = "sim"\nfs_hz = {FS}\nblock_samples = {BLOCK}\npace = "max"\n'
                    '[recording]\nidle_raw = "full"\n[zenoh]\nenabled = false\n'
                    f'[sweep]\nfrequencies_hz = {list(FREQS)}\ndwell_s = {DWELL_S}\n', encoding="utf-8")
    return BenchService(load_daemon_config(toml))


def sweep_end(svc: BenchService) -> tuple[threading.Event, list[dict]]:
    """An Event set by the sweep's last status (done or stopped), and every status, in order."""
    ended, statuses = threading.Event(), []

    def on(topic: str, obj: dict) -> None:
        if topic == "/status":
            statuses.append(dict(obj))
            if obj["event"] in ("sweep_done", "sweep_stopped"):
                ended.set()
    svc.pipeline.listeners.append(on)
    return ended, statuses


def lockstep(svc: BenchService, warmup_blocks: int = 3) -> threading.Event:
    """Hand the source's blocks to the pipeline only while the sweep has a dwell to complete:
    once a dwell is complete, the next block waits until the sweep has acted on it (queued the
    next point, or ended and switched the output off).  The source can then never run ahead of
    the sweep's reaction however busy the machine, so each point's samples are exact; between
    those moments it runs as fast as the pipeline takes it (``pace = "max"``), far faster than
    the wall clock."""
    cond, dwells, ended, warm = threading.Condition(), [], [], threading.Event()

    def spy(n: int) -> threading.Event:  # the dwells the sweep waits on
        with cond:
            dwells.append(type(svc.pipeline).after_samples(svc.pipeline, n))
            cond.notify_all()
            return dwells[-1]

    def on(topic: str, obj: dict) -> None:
        if topic == "/status" and obj["event"] in ("sweep_done", "sweep_stopped"):
            with cond:
                ended.append(obj)
                cond.notify_all()
    blocks = svc.source.blocks

    def gated(stop):  # runs in the pipeline's source thread: the pipeline exists
        svc.pipeline.after_samples = spy
        svc.pipeline.listeners.append(on)
        it = blocks(stop)
        for k in range(warmup_blocks):  # a position to count the first point from
            yield next(it)
        while True:
            warm.set()
            with cond:
                assert cond.wait_for(lambda: ended or (dwells and not dwells[-1].is_set()), HANG_S), \
                    "the sweep never acted on a complete dwell"
            if ended:
                svc._sweep.join(HANG_S)  # its last act: the output off, queued
            b = next(it, None)
            if b is None:  # the pipeline stopped
                return
            yield b
    svc.source.blocks = gated
    return warm


def test_each_point_gets_its_dwell_in_samples_of_the_source_clock(tmp_path: Path) -> None:
    svc = make_service(tmp_path)
    warm = lockstep(svc)
    svc.start()
    try:
        ended, statuses = sweep_end(svc)
        estimates: list[dict] = []
        svc.pipeline.listeners.append(lambda t, o: estimates.append(dict(o)) if t == "/estimate" else None)
        assert warm.wait(HANG_S)  # the warm-up blocks are in: the source waits for the sweep
        svc.command("start_sweep", {})
        assert ended.wait(HANG_S), "the sweep never ended"
    finally:
        paths = svc.stop()
    assert [s for s in statuses if s["event"].startswith("sweep_")][-1]["event"] == "sweep_done", statuses
    on = Counter()  # samples the output was on at each frequency, from the log's raw blocks
    for path in paths:
        for b in iter_blocks(path):
            if b.meta.get("output_on"):
                on[b.meta["frequency_hz"]] += b.n
    assert dict(on) == {f: round(DWELL_S * FS) for f in FREQS}, dict(on)
    per_point = Counter(e["nominal_frequency_hz"] for e in estimates if not e.get("error"))
    assert all(per_point[f] > 0 for f in FREQS), per_point


def test_a_source_that_ends_mid_dwell_stops_the_sweep_with_an_error(tmp_path: Path) -> None:
    svc = make_service(tmp_path)
    svc.source.duration_s = 0.25 * DWELL_S  # the rig's samples end a quarter into the first point
    svc.start()
    try:
        ended, statuses = sweep_end(svc)
        svc.command("start_sweep", {})
        assert ended.wait(HANG_S), "the sweep never ended"
    finally:
        svc.stop()
    last = [s for s in statuses if s["event"].startswith("sweep_")][-1]
    assert last["event"] == "sweep_stopped" and last["level"] == "error", last
    assert "point 0" in last["message"] and "source ended" in last["message"], last
    assert not svc.source.rig.output_enabled


def stall_after_five_blocks(svc) -> tuple[threading.Event, threading.Event]:
    """The service's source gives five blocks, sets ``stalled``, then nothing until ``gate``."""
    gate, stalled = threading.Event(), threading.Event()
    blocks = svc.source.blocks

    def gated(stop):
        for k, b in enumerate(blocks(stop)):
            if k >= 5:
                stalled.set()
                gate.wait(HANG_S)
            yield b
    svc.source.blocks = gated
    return gate, stalled


def test_stop_sweep_interrupts_a_dwell_whose_source_is_stalled(tmp_path: Path, monkeypatch) -> None:
    monkeypatch.setattr(service, "DWELL_STALL_S", HANG_S * 10)  # not the stall bound: stop_sweep ends it
    svc = make_service(tmp_path)
    gate, stalled = stall_after_five_blocks(svc)
    svc.start()
    try:
        ended, statuses = sweep_end(svc)
        pointed = threading.Event()
        svc.pipeline.listeners.append(lambda t, o: pointed.set() if o.get("event") == "sweep_point" else None)
        assert stalled.wait(HANG_S)
        svc.command("start_sweep", {})
        assert pointed.wait(HANG_S)  # a stop before the first point publishes nothing
        assert svc.command("stop_sweep", {}) == {"stopped": True}
        assert ended.is_set() and not svc._sweep.is_alive()
        last = [s for s in statuses if s["event"].startswith("sweep_")][-1]
        assert last["event"] == "sweep_stopped" and last["level"] == "info", last
    finally:
        gate.set()
        svc.stop()


def test_a_stalled_source_ends_the_sweep_with_a_fault_never_a_success(tmp_path: Path, monkeypatch) -> None:
    monkeypatch.setattr(service, "DWELL_STALL_S", 0.2)  # the safety bound, short: the source is dead
    svc = make_service(tmp_path)
    gate, stalled = stall_after_five_blocks(svc)
    svc.start()
    try:
        ended, statuses = sweep_end(svc)
        assert stalled.wait(HANG_S)
        svc.command("start_sweep", {})
        assert ended.wait(HANG_S), "the sweep never ended"
        last = [s for s in statuses if s["event"].startswith("sweep_")][-1]
        assert last["event"] == "sweep_stopped" and last["level"] == "error", last
        assert "no sample from the source" in last["message"], last
    finally:
        gate.set()
        svc.stop()
