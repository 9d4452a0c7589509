"""The optional sidecar key ``start_time_s`` (recording-format.md): checked when present, kept by
write/read, and carried through an MCAP log and ``hystbench export`` as each segment's own start."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from hystbench.analysis.log_recordings import read_mcap_segments
from hystbench.blocks import SampleBlock
from hystbench.cli.main import main
from hystbench.errors import RecordingError
from hystbench.formats.mcaplog import McapRecorder
from hystbench.formats.recording import Recording, read_recording, read_sweep, write_recording

FS = 10_000.0
META = {"rig": "ecore", "frequency_Hz": 80.0, "sample_rate_Hz": FS, "current_pp_A": 1.27}


def _rec(**extra) -> Recording:
    t = np.arange(500) / FS
    return Recording(None, FS, {"current_A": 0.6 * np.sin(2 * np.pi * 80.0 * t)}, {**META, **extra})


@pytest.mark.parametrize("bad", [True, "12.5", None, [1.0], math.nan, math.inf, -math.inf])
def test_a_start_time_that_is_not_a_finite_number_is_refused_naming_the_key(bad) -> None:
    with pytest.raises(RecordingError, match="'start_time_s' must be a finite number"):
        _rec(start_time_s=bad)


@pytest.mark.parametrize("text", ["true", "\"3\"", "null", "{}"])
def test_a_sidecar_with_a_bad_start_time_is_refused_naming_the_file(tmp_path: Path, text: str) -> None:
    write_recording(_rec(), tmp_path / "r")
    side = json.loads((tmp_path / "r.json").read_text())
    (tmp_path / "r.json").write_text(json.dumps(side)[:-1] + f', "start_time_s": {text}}}')
    with pytest.raises(RecordingError, match=r"r\.json: key 'start_time_s'"):
        read_recording(tmp_path / "r")


def test_start_time_round_trips_exactly_and_is_none_when_absent(tmp_path: Path) -> None:
    assert _rec().start_time_s is None
    start = 12345.678901234567  # a day's clock in seconds, all its digits
    write_recording(_rec(start_time_s=start), tmp_path / "r")
    back = read_recording(tmp_path / "r")
    assert back.start_time_s == start and isinstance(back.start_time_s, float)
    write_recording(_rec(start_time_s=7), tmp_path / "i")  # an integer is a number of seconds too
    assert read_recording(tmp_path / "i").start_time_s == 7.0


def _blocks(first: int, n: int, freq: float) -> list[SampleBlock]:
    t = (first + np.arange(n)) / FS
    meta = {"frequency_hz": freq, "current_pp_a": 1.27, "offset_a": 0.0, "output_on": True}
    ch = {"current_A": 0.635 * np.sin(2 * np.pi * freq * t), "force_N": 1.5 + np.sin(2 * np.pi * freq * t)}
    return [SampleBlock(first + k, FS, {c: x[k:k + 1000] for c, x in ch.items()}, meta=dict(meta))
            for k in range(0, n, 1000)]


def test_an_mcap_log_gives_each_segment_its_own_start_and_export_keeps_it(tmp_path: Path) -> None:
    """The log's ``start_time_s`` is when its sample 0 was: a segment starting at sample k started
    k / fs later (what a drift along the day needs), and export writes that into each sidecar."""
    log = tmp_path / "day.mcap"
    with McapRecorder(log, metadata={"recording": {**META, "start_time_s": 100.0}}) as rec:
        for b in _blocks(0, 20_000, 80.0) + _blocks(20_000, 20_000, 320.0):
            rec.add_block(b)
    segs = read_mcap_segments(log)
    assert [s.frequency_hz for s in segs] == [80.0, 320.0]
    for s in segs:  # after the settling the reader skips: the segment's first sample's time
        assert s.start_time_s == pytest.approx(100.0 + s.metadata["mcap_source"]["first_index"] / FS, abs=1e-12)
    assert segs[1].start_time_s > 102.0  # the second point began 2 s into the log
    out = tmp_path / "exported"
    assert main(["export", str(log), "--out", str(out)]) == 0
    back = sorted((read_recording(p.with_suffix("")) for p in out.glob("*.csv")), key=lambda r: r.frequency_hz)
    assert [r.start_time_s for r in back] == [s.start_time_s for s in segs]
    assert [r.rig for r in read_sweep(out)] == ["ecore", "ecore"]


def test_a_log_whose_clock_ran_for_months_is_exported_from_zero_with_its_offset_in_the_start(tmp_path: Path) -> None:
    """A source's sample index runs on: 2e12 samples is 231 days at 100 kS/s, past what float64 holds to
    a thousandth of a period, and export and estimate refused the log ("time_s starts at 2e7 s, too
    far from 0").  The segment now starts at 0, its offset in start_time_s, as the format asks."""
    log = tmp_path / "long.mcap"
    first = 2 * 10**12
    with McapRecorder(log, metadata={"recording": META}) as rec:
        for b in _blocks(first, 20_000, 80.0):
            rec.add_block(b)
    (seg,) = read_mcap_segments(log)
    begun = seg.metadata["mcap_source"]["first_index"]
    assert begun > first and seg.t0_s == 0.0
    assert seg.start_time_s == begun / FS  # the log's sample 0 is the clock's origin (no start_time_s of its own)
    out = tmp_path / "exported"
    assert main(["export", str(log), "--out", str(out)]) == 0
    (back,) = [read_recording(p.with_suffix("")) for p in out.glob("*.csv")]
    assert back.t0_s == 0.0 and back.start_time_s == begun / FS
    np.testing.assert_array_equal(back.channels["current_A"], seg.channels["current_A"])


def test_a_logs_start_time_that_is_no_number_is_named_by_the_readers(tmp_path: Path) -> None:
    log = tmp_path / "bad.mcap"
    with McapRecorder(log, metadata={"recording": {**META, "start_time_s": "noon"}}) as rec:
        for b in _blocks(0, 20_000, 80.0):
            rec.add_block(b)
    with pytest.raises(RecordingError, match=r"bad\.mcap: segment at sample \d+: .*'start_time_s' must be a finite "
                                             r"number of seconds, got 'noon'"):
        read_mcap_segments(log)
