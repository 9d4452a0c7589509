"""The pipeline: record a session, replay it (the same estimates, block for block), the streaming
estimator's independence of block cutting, overruns that are counted, never estimated, and the
compensator hook."""

from __future__ import annotations

import json
import threading
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hystbench.cli.main import main as pipeline_main
from hystbench.acquisition.record import record_log, replay_log
from hystbench.analysis.log_recordings import read_mcap_recording
from hystbench.formats.mcaplog import ESTIMATE, STATS, McapRecorder, McapSource, iter_blocks, iter_log
from hystbench.analysis.method import measure_delays
from hystbench.acquisition.pipeline import CompensatorHook, Pipeline
from hystbench.acquisition.sources import Controllable, RigSource, Source, SyntheticSource
from hystbench.acquisition.stages import WindowEstimator
from hystbench.blocks import SampleBlock, concatenate
from hystbench.errors import ConfigError, RecordingError
from hystbench.messages import CompensatorUpdate, Estimate, OperatingPoint
from hystbench.sim_backend.rig import SimulatedRig


def rig_source(seconds: float = 0.6, block: int = 1000, **kw) -> RigSource:
    rig = SimulatedRig("ecore_pm", frequency_hz=320.0, current_pp_a=1.4, **kw)
    return RigSource(rig, block_samples=block, pace="max", duration_s=seconds)


def same_estimates(a: list, b: list) -> None:
    """Equal, key for key, except the log time (the replay has no recorder clock); estimates as
    :class:`Estimate` s or as their JSON (from a log or a listener)."""
    assert len(a) == len(b) and a
    for x, y in zip(a, b):
        x, y = (e.to_json() if isinstance(e, Estimate) else e for e in (x, y))
        assert {k: v for k, v in x.items() if k != "t_ns"} == {k: v for k, v in y.items() if k != "t_ns"}


def test_sources_follow_the_protocols() -> None:
    src = rig_source()
    assert isinstance(src, Source) and isinstance(src, Controllable)
    assert isinstance(SyntheticSource(pace="max", duration_s=0.01), Source)


def test_record_then_replay_gives_the_same_estimates(tmp_path: Path) -> None:
    src = rig_source(0.8, block=777)
    src.set_excitation(frequency_hz=160.0)  # applied at the first block
    res = record_log(src, tmp_path / "run.mcap", timeout_s=30)
    live = [m.json() for m in iter_log(tmp_path / "run.mcap", [ESTIMATE])]
    assert len(live) == len(res["estimates"]) >= 5 and not any(e["error"] for e in live)
    # every raw sample made it to the log, contiguous, as float32
    bl = list(iter_blocks(tmp_path / "run.mcap"))
    assert bl[0].first_index == 0 and concatenate(bl).n == 80_000
    assert next(iter(bl[0].channels.values())).dtype == np.float32
    # the live estimates are the offline method's on the same window
    rec = read_mcap_recording(tmp_path / "run.mcap")  # the settled part: from the first window on
    e = live[2]
    a, b = (round(i - rec.t0_s * rec.fs_hz) for i in (e["first_index"], e["end_index"]))
    assert 0 <= live[0]["first_index"] - rec.t0_s * rec.fs_hz < 10
    win = rec.__class__(None, rec.fs_hz, {k: v[a:b] for k, v in rec.channels.items()
                                          if k in ("current_A", "flux_Wb", "force_N")},
                        {"rig": "ecore_pm", "frequency_Hz": 160.0, "current_pp_A": 1.4})
    assert measure_delays(win).delays_s == e["delays_s"]
    assert 0.8 < e["phases_deg"]["hysteresis"] < 1.3  # the simulated iron at 160 Hz
    # replay through the same pipeline: the same estimates, block for block
    same_estimates(replay_log(tmp_path / "run.mcap"), live)
    # ... and recorded again, the same again
    same_estimates(replay_log(tmp_path / "run.mcap", out=tmp_path / "again.mcap"), live)
    # a replay never replaces the log it replays; one that fails late (a damaged chunk) leaves the log
    # it was to replace as it was, and no part of its own
    kept = (tmp_path / "again.mcap").read_bytes()
    with pytest.raises(ConfigError, match="the command reads"):
        replay_log(tmp_path / "again.mcap", out=tmp_path / "again.mcap", overwrite=True)
    data = bytearray((tmp_path / "run.mcap").read_bytes())
    data[int(0.6 * len(data)):int(0.6 * len(data)) + 64] = bytes(64)
    (tmp_path / "damaged.mcap").write_bytes(bytes(data))
    with pytest.raises(RecordingError, match=r"again\.mcap: recording failed"):
        replay_log(tmp_path / "damaged.mcap", out=tmp_path / "again.mcap", overwrite=True)
    assert (tmp_path / "again.mcap").read_bytes() == kept
    assert sorted(p.name for p in tmp_path.iterdir()) == ["again.mcap", "damaged.mcap", "run.mcap"]
    assert [m.json() for m in iter_log(tmp_path / "run.mcap", [STATS])][-1]["stages"]["record"]["lost_samples"] == 0


@settings(max_examples=12, deadline=None)
@given(cuts=st.lists(st.integers(1, 3000), min_size=1, max_size=8))
def test_estimates_do_not_depend_on_how_the_stream_is_cut(cuts: list[int]) -> None:
    big = _STREAM
    ref = _REF
    we = WindowEstimator(big.fs_hz, {"rig": "ecore_pm", "frequency_Hz": 320.0, "current_pp_A": 1.4})
    out, i, k = [], 0, 0
    while i < big.n:
        n = cuts[k % len(cuts)]
        out += we.push(SampleBlock(i, big.fs_hz, {c: x[i:i + n] for c, x in big.channels.items()}, meta=big.meta))
        i, k = i + n, k + 1
    same_estimates(out, ref)


_src = rig_source(0.25)
_STREAM = concatenate(list(_src.blocks()))
_REF = WindowEstimator(_STREAM.fs_hz, _src.metadata()).push(_STREAM)


def test_estimator_runs_reset_at_changes_gaps_and_output_off() -> None:
    meta = {"rig": "ecore_pm", "frequency_Hz": 320.0, "current_pp_A": 1.4}
    we = WindowEstimator(_STREAM.fs_hz, meta, periods=4, settle_periods=0, min_hop_s=0)
    n = _STREAM.n
    h = n // 2
    first = SampleBlock(0, _STREAM.fs_hz, {c: x[:h] for c, x in _STREAM.channels.items()}, meta=_STREAM.meta)
    second = SampleBlock(h + 50, _STREAM.fs_hz, {c: x[h:] for c, x in _STREAM.channels.items()}, meta=_STREAM.meta)
    out = we.push(first) + we.push(second)  # the gap starts a new run: no window straddles it
    assert out and all(e.end_index <= h or e.first_index >= h + 50 for e in out)
    off = dict(_STREAM.meta, output_on=0.0)
    assert we.push(SampleBlock(n + 100, _STREAM.fs_hz, dict(_STREAM.channels), meta=off)) == []
    flat = {c: np.full(2000, 1.0) for c in _STREAM.channels}  # output "on" but nothing there
    bad = WindowEstimator(_STREAM.fs_hz, meta, periods=4, settle_periods=0, settle_s=0).push(
        SampleBlock(0, _STREAM.fs_hz, flat, meta=_STREAM.meta))
    assert bad and "flat" in bad[0].error
    # a block that claims 0 Hz (a damaged log's) has no period to window by: no estimate, no end of the
    # stage (a division by it ended a replay); the run after it is estimated as before
    zero = dict(_STREAM.meta, frequency_hz=0.0)
    we = WindowEstimator(_STREAM.fs_hz, meta, periods=4, settle_periods=0, min_hop_s=0)
    assert we.push(SampleBlock(0, _STREAM.fs_hz, dict(_STREAM.channels), meta=zero)) == []
    again = we.push(SampleBlock(n + 100, _STREAM.fs_hz, dict(_STREAM.channels), meta=_STREAM.meta))
    assert again and not again[0].error


class _Finished(SyntheticSource):
    """A synthetic source that says when it has handed out its last block."""

    def __init__(self, **kw) -> None:
        super().__init__(**kw)
        self.done = threading.Event()

    def blocks(self, stop=None):
        yield from super().blocks(stop)
        self.done.set()


def gated(est: WindowEstimator, gate: threading.Event) -> WindowEstimator:
    """The estimator, stuck in its first ``append`` until ``gate`` is set: the slowest stage there
    can be, without any timing."""
    real_append = est.append

    def slow_append(block):
        assert gate.wait(60), "the gate never opened"
        real_append(block)

    est.append = slow_append
    return est


def test_a_lagging_live_stage_loses_counted_samples_and_never_estimates_torn_data() -> None:
    """Live (not lossless), the source never waits: a stage stuck until the source has finished is
    lapped by the ring; what it lost is counted and nothing torn is estimated."""
    src = _Finished(fs_hz=100_000.0, block_samples=2000, pace="max", duration_s=1.0)
    gate = threading.Event()
    est = gated(WindowEstimator(src.fs_hz, src.metadata(), periods=4, settle_periods=0, settle_s=0, min_hop_s=0),
                gate)
    pipe = Pipeline(src, estimator=est, ring_seconds=0.05, lossless=False)
    got = []
    pipe.listeners.append(lambda t, o: got.append(o))
    pipe.start()
    assert src.done.wait(60)
    gate.set()
    assert pipe.join(60)
    st_ = pipe.stats["estimate"]
    r = pipe._readers["estimate"]
    assert r.lost_samples > 0 and r.read_samples + r.lost_samples == 100_000
    ests = [o for o in got if "end_index" in o and "delays_s" in o]
    assert len(ests) >= 3
    for e in ests:  # every estimate that came out is right (synthetic flux lag: 10 us)
        assert abs(e["delays_s"]["hysteresis"] - 10e-6) < 0.5e-6
    assert st_.lost_samples == r.lost_samples
    assert any(o.get("event") == "estimator_overrun" for o in got)


def _same_blocks(a: Path, b: Path) -> None:
    """The two logs hold the same raw blocks, block for block: indices, flags, meta and samples."""
    x, y = list(iter_blocks(a)), list(iter_blocks(b))
    assert len(x) == len(y) and x
    for p, q in zip(x, y):
        assert (p.first_index, p.n, int(p.flags), p.gap_samples, dict(p.meta)) == \
               (q.first_index, q.n, int(q.flags), q.gap_samples, dict(q.meta))
        assert set(p.channels) == set(q.channels)
        for c in p.channels:
            np.testing.assert_array_equal(p.channels[c], q.channels[c])


class _WatchedReplay(McapSource):
    """The replay source, saying when it has handed out its last block."""

    def __init__(self, *a, **kw) -> None:
        super().__init__(*a, **kw)
        self.done = threading.Event()

    def blocks(self, stop=None):
        yield from super().blocks(stop)
        self.done.set()


def test_replay_is_lossless_and_equals_live_block_for_block_at_both_speeds(tmp_path: Path) -> None:
    """Issue 10: a replay at --speed max overran its estimator and lost estimates.  Offline, the
    source now waits for the slowest stage: with an estimator stuck until the source is either
    held back (lossless) or done (it lapped the stage), the replay gives every live estimate and
    records every raw block as the live run did; the realtime replay does too."""
    src = SyntheticSource(fs_hz=20_000.0, block_samples=500, pace="max", duration_s=0.5, noise=1e-3, seed=4)
    settings_ = {"periods": 4.0, "min_hop_s": 0.0, "settle_periods": 0.0}
    live_log = tmp_path / "live.mcap"
    res = record_log(src, live_log, estimation=settings_, timeout_s=60)
    live = [m.json() for m in iter_log(live_log, [ESTIMATE])]
    assert len(live) == len(res["estimates"]) >= 30 and not any(e["error"] for e in live)
    assert concatenate(list(iter_blocks(live_log))).n == 10_000

    # max speed, with the slowest stage there is: the ring (1200 samples) is far shorter than the log
    replay = _WatchedReplay(live_log, pace="max")
    gate = threading.Event()
    est = gated(WindowEstimator(replay.fs_hz, replay.metadata(), **settings_), gate)
    with McapRecorder(tmp_path / "max.mcap", metadata={"recording": replay.metadata()}) as rec:
        pipe = Pipeline(replay, estimator=est, recorder=rec, dtype=replay.dtype, ring_seconds=0.06)
        assert pipe.lossless  # a source paced "max" is offline
        opener = threading.Thread(target=lambda: (getattr(pipe, "backpressure", replay.done).wait(60) or
                                                  replay.done.wait(60), gate.set()))
        ests = []
        pipe.listeners.append(lambda t, o: ests.append(o) if t == ESTIMATE else None)
        pipe.start()
        opener.start()
        assert pipe.join(60) and pipe.error is None
        opener.join(60)
    assert pipe.stats["estimate"].lost_samples == 0 and pipe.stats["record"].lost_samples == 0
    same_estimates(ests, live)
    _same_blocks(tmp_path / "max.mcap", live_log)

    # realtime keeps the live behaviour (a stage that keeps up loses nothing) and gives the same
    realtime = replay_log(live_log, speed="realtime", out=tmp_path / "rt.mcap")
    same_estimates(realtime, live)
    _same_blocks(tmp_path / "rt.mcap", live_log)
    assert not Pipeline(McapSource(live_log, pace="realtime")).lossless
    # ... and so does the plain replay command's path at max speed
    same_estimates(replay_log(live_log), live)


class FakeCompensator:
    def __init__(self) -> None:
        self.seen = []

    def update(self, estimate: Estimate) -> CompensatorUpdate:
        self.seen.append(estimate)
        if len(self.seen) == 2:
            raise RuntimeError("model not ready")
        return CompensatorUpdate({"gain": 1.0 + len(self.seen)},
                                 waveform_a=np.sin(np.linspace(0, 2 * np.pi, 64, endpoint=False)), frequency_hz=320.0)


def test_compensator_hook_publishes_state_applies_waveforms_and_survives_errors() -> None:
    src = rig_source(0.6)
    waves = []
    src.set_waveform = lambda table, f: waves.append((len(table), f))
    comp = FakeCompensator()
    pipe = Pipeline(src, estimator=WindowEstimator(src.fs_hz, src.metadata()), compensator=CompensatorHook(comp, src))
    states = []
    pipe.listeners.append(lambda t, o: states.append(o) if t == "/compensator" else None)
    pipe.start()
    assert pipe.join(30) and pipe.error is None
    assert len(comp.seen) >= 3 and len(states) == len(comp.seen)
    assert "model not ready" in states[1]["error"]
    assert states[0]["gain"] == 2.0 and states[0]["waveform_applied"] and "waveform_a" not in states[0]
    assert waves and waves[0] == (64, 320.0)


class _Commands:
    """A Controllable that only notes the commands it is given, in order."""

    def __init__(self) -> None:
        self.done: list[tuple] = []

    def set_excitation(self, frequency_hz=None, current_pp_a=None, offset_a=None) -> None:
        self.done.append(("excitation", frequency_hz, current_pp_a, offset_a))

    def set_output(self, on: bool) -> None:
        self.done.append(("output", on))

    def set_waveform(self, current_a: np.ndarray, frequency_hz: float) -> None:
        self.done.append(("waveform", len(current_a), frequency_hz))


def test_the_hook_applies_the_update_fields_and_publishes_only_the_state() -> None:
    """The update's commands are typed fields apart from its state: output off first, then the
    waveform (at its frequency, else the estimate's); the state is published with what was done."""
    est = Estimate(0, 100, 0, nominal_frequency_hz=160.0, current_pp_a=1.0, frequency_hz=160.01,
                   delays_s={"hysteresis": 1e-5})
    both = CompensatorUpdate({"status": "stopped: diverging", "frequency_hz": 999.0}, output_off=True,
                             waveform_a=[0.0, 1.0, 0.0, -1.0])
    replies = iter([both, CompensatorUpdate({"k": 1}), None, {"waveform_a": [0.0, 1.0], "output_off": True}])

    class Comp:
        def update(self, estimate: Estimate) -> object:
            return next(replies)

    src = _Commands()
    hook = CompensatorHook(Comp(), src)
    assert isinstance(src, Controllable)
    state = hook(est)
    assert src.done == [("output", False), ("waveform", 4, 160.0)]  # not the state's frequency_hz: not a command
    assert state == {"status": "stopped: diverging", "frequency_hz": 999.0, "output_switched_off": True,
                     "waveform_applied": True}
    assert hook.tripped == "stopped: diverging"
    assert hook(est) == {"k": 1} and hook(est) is None and len(src.done) == 2
    # an untyped dict is someone else's old-style state: refused and reported, its "commands" not applied
    refused = hook(est)
    assert "CompensatorUpdate" in refused["error"] and hook.errors == 1 and len(src.done) == 2
    with pytest.raises(ValueError, match="waveform_a"):
        CompensatorUpdate({}, waveform_a=np.zeros((2, 3)))


def test_a_waveform_beyond_the_limit_is_a_trip_of_the_compensator_not_a_fault() -> None:
    """A compensator whose table peaks at 2 A on a 1.71 A bench: the source refuses it (ConfigError),
    and the hook used to let that out of the pipeline as a fault, so six ``output on`` within a minute
    stopped the service.  Now the output goes off, the hook is tripped (output on refused until a
    reload) and the state says why; nothing is raised."""
    from hystbench.acquisition.sources import RigSource
    from hystbench.sim_backend.rig import SimulatedRig

    est = Estimate(0, 100, 0, nominal_frequency_hz=40.0, current_pp_a=1.0, frequency_hz=40.0,
                   delays_s={"hysteresis": 1e-5})

    class TooMuch:
        def update(self, estimate: Estimate) -> CompensatorUpdate:
            return CompensatorUpdate({"status": "tracking"}, waveform_a=2.0 * np.sin(2 * np.pi * np.arange(64) / 64))

    rig = SimulatedRig("voicecoil_ferrite", frequency_hz=40.0)
    src = RigSource(rig, block_samples=100, pace="max", max_current_a=1.71)
    hook = CompensatorHook(TooMuch(), src)
    state = hook(est)
    assert rig.output_enabled is False and state["output_switched_off"] is True
    assert "beyond the bench's max_current_a = 1.71 A" in state["waveform_refused"]
    assert "waveform_applied" not in state and hook.tripped.startswith("its waveform was refused")
    assert hook.errors == 0
    src.close()


def test_stop_is_prompt_and_a_failing_source_is_reported() -> None:
    src = SyntheticSource(fs_hz=100_000.0, block_samples=1000, pace="realtime")  # endless
    pipe = Pipeline(src, estimator=WindowEstimator(src.fs_hz, src.metadata())).start()
    assert pipe.after_samples(3 * 1000).wait(60.0)  # three blocks flowed (the timeout only bounds a hang)
    assert pipe.stats["source"].blocks >= 3
    pipe.stop(60.0)
    assert pipe.finished.is_set()  # the source is endless: only the stop can have ended it

    class Broken:
        name, channels, fs_hz = "broken", ["current_A"], 1000.0

        def metadata(self):
            return {}

        def blocks(self, stop=None):
            yield SampleBlock(0, 1000.0, {"current_A": np.zeros(10)})
            raise OSError("cable pulled")

        def close(self):
            pass

    p = Pipeline(Broken()).start()
    assert p.join(5.0) and isinstance(p.error, OSError)


def test_a_replay_whose_every_window_is_refused_says_so_and_fails(tmp_path: Path, capsys) -> None:
    """A synthetic sine on the E-core without a magnet has no force at 2 f: every window refused.  The
    replay said "7 estimates from ..." and exit 0, and its --json held bare NaN, which is no JSON."""
    log = tmp_path / "s.mcap"
    assert pipeline_main(["record", "--out", str(log), "--source", "synthetic", "--rig", "ecore", "--freq", "80",
                          "--seconds", "1", "--pace", "max"]) == 0
    said = capsys.readouterr().out
    n = int(said.split(" estimates (")[0].rsplit(" ", 1)[1])
    assert n > 0 and f"{n} estimates ({n} refused)" in said  # record's own count
    assert pipeline_main(["replay", str(log)]) == 1
    out, err = capsys.readouterr()
    assert out.strip().splitlines()[-1] == f"{n} estimates ({n} refused) from {log}"
    assert f"every one of the {n} windows of {log} was refused (the first: ecore window at 80 Hz" in err
    assert pipeline_main(["replay", "--json", str(log)]) == 1

    def no_constant(name: str):
        raise AssertionError(f"{name} is no JSON")
    ests = json.loads(capsys.readouterr().out, parse_constant=no_constant)
    assert len(ests) == n and all(e["error"] for e in ests)


def test_record_replay_export_recover_commands(tmp_path: Path, capsys) -> None:
    log = tmp_path / "c.mcap"
    assert pipeline_main(["record", "--out", str(log), "--source", "sim", "--seconds", "0.3", "--pace", "max",
                          "--freq", "160"]) == 0
    assert "30000 samples" in capsys.readouterr().out
    assert pipeline_main(["record", "--out", str(log), "--source", "sim", "--seconds", "0.1"]) == 2
    assert "already exists" in capsys.readouterr().err
    assert pipeline_main(["replay", str(log)]) == 0
    assert "hysteresis" in capsys.readouterr().out
    capsys.readouterr()
    assert pipeline_main(["export", str(log), "--out", str(tmp_path / "x")]) == 0
    written = tmp_path / "x" / "ecore_pm_160Hz_1.4App.csv"
    assert written.exists() and f"wrote {written} " in capsys.readouterr().out  # it said '..._1.csv'
    assert pipeline_main(["recover", str(log), "--json"]) == 0
    assert '"complete": true' in capsys.readouterr().out
    syn = tmp_path / "s.mcap"
    assert pipeline_main(["record", "--out", str(syn), "--source", "synthetic", "--fs", "1e6", "--block", "10000",
                          "--seconds", "0.2", "--pace", "max", "--compression", "lz4"]) == 0


def test_record_through_the_drivers_and_the_emulated_instruments(tmp_path: Path, capsys) -> None:
    """The default source: the shipped bench file, every instrument emulated behind its protocol."""
    log = tmp_path / "bench.mcap"
    assert pipeline_main(["record", "--out", str(log), "--seconds", "1.0", "--freq", "320"]) == 0
    assert "100000 samples x 4 channels" in capsys.readouterr().out
    bl = list(iter_blocks(log))
    assert all(b.first_index == a.end_index for a, b in zip(bl, bl[1:]))  # aligned, nothing lost
    # the first samples (before the switch-on command, applied once the streams deliver) are off;
    # then the switch-on is marked settling, and the rest of the record is settled
    off = [b.meta["output_on"] == 0.0 for b in bl]
    assert off == sorted(off, reverse=True)
    bl = bl[sum(off):]
    settling = [bool(b.meta.get("settling")) for b in bl]
    assert settling[0] and settling == sorted(settling, reverse=True) and not settling[-1]
    # ... and the current really came on inside the marks (counted from the first sample, not from 0):
    # every period after them carries the full 1.4 A-pp
    settled = concatenate([b for b, s_ in zip(bl, settling) if not s_])
    assert settled.meta["output_on"] == 1.0
    i = settled.channels["current_A"]
    period = 313  # samples of one 320 Hz period at 100 kS/s, rounded up
    assert min(np.ptp(i[k:k + period]) for k in range(0, i.size - period, period)) > 0.95 * 1.4
    est = [m.json() for m in iter_log(log, [ESTIMATE])]
    good = [e for e in est if not e["error"]]
    assert len(good) >= 3 and all(1.2 < e["phases_deg"]["hysteresis"] < 1.5 for e in good)
    rec = read_mcap_recording(log)  # the settled part, as one recording: the end of the blocks marked so
    # (how much of the second that is depends on how long the switch-on waited for the streams' live
    # edge, a busy machine's startup, so it is not asserted: with -n 6 on 2 cores it was 0.32 s)
    first = rec.metadata["mcap_source"]["first_index"]
    assert settled.first_index <= first and first + rec.n == settled.end_index and rec.n > 0
    assert set(rec.channels) == {"current_A", "force_N", "flux_Wb", "command_V"}
    np.testing.assert_array_equal(rec.channels["current_A"], i[first - settled.first_index:])


def test_the_pipeline_gives_back_the_interpreter_switch_interval() -> None:
    # Found by `make demo`: a 0.5 ms switch interval left behind starved the drivers that ran next.
    import sys

    before = sys.getswitchinterval()
    source = _HeldSource(SimulatedRig("voicecoil_ferrite"), duration_s=0.05, block_samples=1000, pace="max")
    pipe = Pipeline(source)
    pipe.start()
    assert sys.getswitchinterval() < before  # the source holds its first block: the pipeline is running
    source.release.set()
    assert pipe.join(10.0)
    assert sys.getswitchinterval() == before


class _HeldSource(RigSource):
    """A rig source that gives its first block only once ``release`` is set, so a test sees the
    pipeline running however late the machine schedules it (a 0.05 s record at full pace used to be
    over, under load, before the test could look)."""

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.release = threading.Event()

    def blocks(self, stop=None):
        if not self.release.wait(30.0):
            raise TimeoutError("the test never released the source")
        yield from super().blocks(stop)


def test_every_change_of_what_the_generator_plays_starts_a_new_run() -> None:
    """A waveform upload, and a sine set again after it, each move the blocks' ``table`` count on,
    so the estimator never mixes two waveforms in one window (the learning compensator relies on
    it); estimates name their table."""
    rig = SimulatedRig("ecore_pm", seed=2, frequency_hz=320.0, current_pp_a=1.4)
    src = RigSource(rig, block_samples=5000, pace="max")
    est = WindowEstimator(src.fs_hz, src.metadata(), periods=10, settle_periods=1, min_hop_s=0)
    table = 0.7 * np.sin(np.linspace(0, 2 * np.pi, 500, endpoint=False))
    blocks, out, span = src.blocks(), [], 3 * 5000  # each waveform plays for three blocks
    for step in range(9):
        if step == 3:
            src.set_waveform(table, 320.0)
        if step == 6:
            src.set_excitation(frequency_hz=320.0)  # the same sine again: the table is gone
        b = next(blocks)
        assert b.meta["table"] == step // 3
        out += est.push(b)
    for e in out:  # every window lies within the blocks of its own waveform
        assert e.table == e.first_index // span == (e.end_index - 1) // span, e
    assert {e.table for e in out} == {0, 1, 2}


def test_a_learning_hook_gets_the_windows_and_the_published_estimates_do_not() -> None:
    src = rig_source(0.6)
    got = []

    class Learner:
        learns = True

        def update(self, estimate: Estimate, window: SampleBlock | None = None) -> None:
            got.append((estimate, window))

    hook = CompensatorHook(Learner(), src)
    est = WindowEstimator(src.fs_hz, src.metadata(), keep_windows=hook.wants_windows)
    pipe = Pipeline(src, estimator=est, compensator=hook)
    published = []
    pipe.listeners.append(lambda t, o: published.append(o) if t == ESTIMATE else None)
    pipe.start()
    assert pipe.join(30) and pipe.error is None
    assert published and all("window" not in e and e["table"] == 0 for e in published)
    e, w = got[0]
    assert isinstance(w, SampleBlock) and w.n == e.end_index - e.first_index and w.first_index == e.first_index
    assert set(w.channels) >= {"current_A", "force_N", "flux_Wb", "command_V"} and w.fs_hz == src.fs_hz
    assert OperatingPoint.from_meta(w.meta) == OperatingPoint(320.0, 1.4, table=0)
    # the window's samples are the source's own (as the ring's float32 held them) from its first index on
    whole = concatenate(list(rig_source(0.6).blocks()))
    i = w.first_index - whole.first_index
    np.testing.assert_array_equal(w.channels["force_N"], whole.channels["force_N"][i:i + w.n].astype(np.float32))


def test_the_estimator_reads_the_rig_preset_when_made_not_for_each_window(monkeypatch) -> None:
    """Each window used to be wrapped in a Recording, which checked the sidecar against the rig
    presets, and the method then read the rig's TOML again: for every window.  What the estimator
    needs of the preset (an E-core? a magnet?) is read when it is made; windows read none."""
    import hystbench.acquisition.stages as stages
    import hystbench.analysis.method as method
    import hystbench.analysis.settling as settling
    import hystbench.config as config
    import hystbench.formats.recording as recording

    reads: list[str] = []
    for mod, name in ((config, "load_rig"), (stages, "load_rig"), (method, "load_rig"), (settling, "load_rig"),
                      (recording, "rig_names")):
        real = getattr(mod, name)  # the real reader runs; the spy only counts
        monkeypatch.setattr(mod, name,
                            lambda *a, _real=real, _name=name, **kw: (reads.append(_name), _real(*a, **kw))[1])
    est = WindowEstimator(_STREAM.fs_hz, _src.metadata(), periods=4, min_hop_s=0)
    assert reads  # made: the preset is read
    reads.clear()
    out = est.push(_STREAM)
    assert len(out) >= 10 and not any(e.error for e in out)
    assert reads == []
    assert out == WindowEstimator(_STREAM.fs_hz, _src.metadata(), periods=4, min_hop_s=0).push(_STREAM)


def test_the_estimator_compiles_its_fits_when_made_not_at_the_first_window() -> None:
    """In a fresh process (numba compiles per process: 0.5 s from its cache, seconds cold) the fits'
    kernels are ready once the stage exists, so the stream does not fill the ring behind a first
    window that compiles them."""
    import subprocess
    import sys

    code = ("from hystbench import jit\n"
            "from hystbench.acquisition.stages import WindowEstimator\n"
            "from hystbench.analysis.estimation import _lsq_kernel as k\n"
            "WindowEstimator(1e5, {'rig': 'ecore_pm', 'frequency_Hz': 320.0, 'current_pp_A': 1.0})\n"
            "print(jit.enabled(), bool(k.basis.signatures), bool(k.gram_solve.signatures))\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300, check=True)
    enabled, basis, solve = out.stdout.split()
    assert enabled == "False" or (basis, solve) == ("True", "True")


def test_two_pipelines_whose_lives_overlap_give_back_the_switch_interval() -> None:
    """The first lowers it, the second starts while it is low; whichever ends last must restore the
    value from before the first (the second's start saw only the lowered one)."""
    import sys

    before = sys.getswitchinterval()
    first = Pipeline(RigSource(SimulatedRig("voicecoil_ferrite"), duration_s=0.05, block_samples=1000, pace="max")).start()
    held = _HeldSource(SimulatedRig("voicecoil_ferrite"), duration_s=0.05, block_samples=1000, pace="max")
    second = Pipeline(held).start()
    assert first.join(10.0)
    assert sys.getswitchinterval() < before  # the second still runs (its source holds its first block)
    held.release.set()
    assert second.join(10.0)
    assert sys.getswitchinterval() == before


def test_a_pipeline_nobody_joins_still_gives_back_the_switch_interval() -> None:
    """The threads' end gives it back, not a join: a pipeline whose owner never joins it (or gave up
    waiting) must not keep the process's switch interval lowered."""
    import sys

    before = sys.getswitchinterval()
    source = _HeldSource(SimulatedRig("voicecoil_ferrite"), duration_s=0.05, block_samples=1000, pace="max")
    pipe = Pipeline(source).start()
    assert sys.getswitchinterval() < before
    source.release.set()
    for t in list(pipe._threads):  # wait for the threads themselves, not through the pipeline
        t.join(10.0)
    assert sys.getswitchinterval() == before


def test_a_stop_finishes_the_log_without_waiting_for_an_estimator_far_behind(tmp_path: Path) -> None:
    """``[estimation] hop_periods = 0.1, min_hop_s = 0`` put a daemon's estimator far behind; on SIGTERM
    the record stage waited for its last estimates, the stop bound passed and the log was left
    without its footer.  Stopped, the record stage waits for the estimator only until 80 % of the
    stop's timeout: here it is stuck (gated) for good, and the record stage still ends, its log whole."""
    src = _Finished(fs_hz=100_000.0, block_samples=2000, pace="max", duration_s=0.2)
    gate = threading.Event()
    est = gated(WindowEstimator(src.fs_hz, src.metadata(), periods=4, settle_periods=0, settle_s=0, min_hop_s=0),
                gate)
    log = tmp_path / "stopped.mcap"
    try:
        with McapRecorder(log, metadata={"recording": src.metadata()}) as rec:
            pipe = Pipeline(src, estimator=est, recorder=rec, ring_seconds=0.5, lossless=False)
            pipe.start()
            assert src.done.wait(60)
            pipe.stop(timeout_s=0.5)
            (record,) = [t for t in pipe._threads if t.name == "pipeline-record"]
            record.join(60)  # an event, not a time: it ends, or (before) it waited for the gate for good
            assert not record.is_alive()
        assert concatenate(list(iter_blocks(log))).n == 20_000  # every sample, in a log the reader takes
    finally:
        gate.set()


def test_a_ring_beyond_the_pipelines_memory_is_refused_naming_the_rate() -> None:
    """``record --source synthetic --fs 1e9`` asked numpy for a 29.8 GiB ring: a MemoryError traceback
    and a stray log.  Refused before anything is allocated, saying the size and what to lower."""
    from hystbench.acquisition.pipeline import MAX_RING_BYTES

    src = SyntheticSource(fs_hz=1e9, block_samples=1000, pace="max", duration_s=1e-6)
    with pytest.raises(ConfigError, match=r"a ring of 2 s at 1e\+09 S/s x \d channels is \d+\.\d GiB, more than the 2 GiB"):
        Pipeline(src)
    assert 2 * 16e6 * 4 * 4 < MAX_RING_BYTES  # the pipeline benchmark's 4 channels, even at 16 MS/s each, fit
