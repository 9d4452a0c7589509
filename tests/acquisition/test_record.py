"""``acquisition.record``: what ``hystbench record`` keeps when a recording fails, and how it says so.

A log whose blocks were all sampled with the output off holds no measurement (the bench's idle
samples before the first command); ``has_measurement`` reads each block's output state through
``OperatingPoint`` (the one reading of block meta), on real MCAP files."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from hystbench.acquisition.record import has_measurement, record_log, replay_log
from hystbench.blocks import SampleBlock
from hystbench.errors import RecordingError
from hystbench.formats.mcaplog import McapRecorder, McapSource
from hystbench.formats.mcaplog.reader import iter_blocks
from hystbench.messages import OperatingPoint

FS = 10_000.0


def _log(path: Path, metas: list[dict[str, float]]) -> Path:
    """A log of one 100-sample block per meta, contiguous, every block written (idle_raw full)."""
    with McapRecorder(path, idle_raw="full") as rec:
        for k, meta in enumerate(metas):
            rec.add_block(SampleBlock(100 * k, FS, {"current_A": np.zeros(100)}, meta=meta))
    return path


def test_only_samples_with_the_output_on_are_a_measurement(tmp_path: Path) -> None:
    off = OperatingPoint(320.0, 1.4, output_on=False).to_meta()
    on = OperatingPoint(320.0, 1.4).to_meta()
    settling_on = OperatingPoint(320.0, 1.4, settling=True).to_meta()
    assert not has_measurement(_log(tmp_path / "idle.mcap", [off, off, off]))
    assert has_measurement(_log(tmp_path / "late.mcap", [off, off, on]))
    assert has_measurement(_log(tmp_path / "settling.mcap", [off, settling_on]))  # sampled with the output on
    assert has_measurement(_log(tmp_path / "bare.mcap", [{}]))  # no operating point: the output taken as on


def test_an_unreadable_log_counts_as_a_measurement(tmp_path: Path) -> None:
    """Nothing that may hold data is deleted on its strength."""
    bad = tmp_path / "cut.mcap"
    good = _log(tmp_path / "whole.mcap", [OperatingPoint(320.0, 1.4, output_on=False).to_meta()])
    bad.write_bytes(good.read_bytes()[:40])
    assert has_measurement(bad)


# --- a pipeline that fails: the error names the log, as a RecordingError ----------------------------
def cut_log(tmp_path: Path) -> Path:
    """A log of 20 blocks whose 15th raw message has a character base64 does not allow: the reader
    gives the first blocks, then fails in the pipeline's source thread (what a damaged disk does)."""
    path = _whole_log(tmp_path / "damaged.mcap", seed=1)
    data = path.read_bytes()
    at = -1
    for _ in range(15):  # the 15th block's data
        at = data.index(b'"data":"', at + 1)
    path.write_bytes(data[:at + 20] + b"!" + data[at + 21:])
    return path


def test_a_replay_whose_source_fails_is_a_recording_error_naming_the_log(tmp_path: Path) -> None:
    log = cut_log(tmp_path)
    with pytest.raises(RecordingError, match=r"damaged\.mcap: replay failed: .*damaged\.mcap: raw message") as info:
        replay_log(log)
    assert isinstance(info.value.__cause__, RecordingError)  # the reader's own error, kept as the cause


def test_a_recording_whose_source_fails_is_a_recording_error_naming_the_output(tmp_path: Path) -> None:
    out = tmp_path / "out.mcap"
    with pytest.raises(RecordingError, match=r"out\.mcap: recording failed: .*damaged\.mcap"):
        record_log(McapSource(cut_log(tmp_path)), out)
    assert out.is_file() and has_measurement(out)  # what came before the damage is kept


def test_the_command_line_says_a_failed_replay_in_one_line_exit_2(tmp_path: Path, capsys) -> None:
    from hystbench.cli.main import main

    log = cut_log(tmp_path)
    assert main(["replay", str(log)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"hystbench replay: error: {log}: replay failed: ") and "raw message" in err
    assert "\n" not in err and "Traceback" not in err


def test_a_ctrl_c_as_the_threads_start_stops_them_before_the_log_is_closed(tmp_path: Path, monkeypatch) -> None:
    """The interrupt arriving at the end of ``Pipeline.start`` (its threads running): the pipeline is
    stopped and drained first, then the log is finished; it holds every block the source gave, in
    order.  It used to escape record_log with the threads still writing into a log being closed."""
    from hystbench.acquisition.pipeline import Pipeline

    real_start = Pipeline.start

    def start_then_interrupt(self):
        real_start(self)
        raise KeyboardInterrupt

    monkeypatch.setattr(Pipeline, "start", start_then_interrupt)
    src = McapSource(_whole_log(tmp_path / "whole_source.mcap", seed=2))
    out = tmp_path / "out.mcap"
    summary = record_log(src, out)
    # The interrupt may come before the source's thread gave its first block: then the finished log
    # holds none, which is still a whole log.  Whatever it holds is the source's first blocks, gapless
    # (as the recorder stores samples: float32).
    kept = list(iter_blocks(out))
    source = list(iter_blocks(tmp_path / "whole_source.mcap"))
    assert [b.first_index for b in kept] == [b.first_index for b in source[:len(kept)]]
    assert all(np.array_equal(a.channels["current_A"], b.channels["current_A"].astype(np.float32)) for a, b in zip(kept, source))
    assert summary["samples"] == sum(b.n for b in kept)


def _whole_log(path: Path, seed: int) -> Path:
    """A log of 20 blocks of 1000 noise samples of one channel, the output on."""
    meta = OperatingPoint(320.0, 1.4).to_meta()
    rng = np.random.default_rng(seed)
    with McapRecorder(path, compression="none", idle_raw="full",
                      metadata={"recording": {"rig": "ecore_pm", "frequency_Hz": 320.0, "sample_rate_Hz": FS,
                                              "current_pp_A": 1.4}}) as rec:
        for k in range(20):
            rec.add_block(SampleBlock(1000 * k, FS, {"current_A": rng.standard_normal(1000)}, meta=meta))
    return path
