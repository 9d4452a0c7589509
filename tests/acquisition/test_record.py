"""``acquisition.record``: what ``hystbench record`` keeps when a recording fails.

A log whose blocks were all sampled with the output off holds no measurement (the bench's idle
samples before the first command); ``has_measurement`` reads each block's output state through
``OperatingPoint`` (the one reading of block meta), on real MCAP files."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from hystbench.acquisition.record import has_measurement
from hystbench.blocks import SampleBlock
from hystbench.formats.mcaplog import McapRecorder
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
