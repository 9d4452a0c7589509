"""Issue 30, item 5: ``estimate`` on an MCAP log of several segments names the option that picks
one (``--segment``) and lists the segments with their numbers."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from hystbench.acquisition.sources import operating_meta
from hystbench.blocks import SampleBlock
from hystbench.cli.main import main
from hystbench.formats.mcaplog import McapRecorder

FS = 10_000.0
META = {"rig": "ecore_pm", "frequency_Hz": 320.0, "sample_rate_Hz": FS, "current_pp_A": 1.4}


def _blocks(freq: float, start: int, n_blocks: int = 4, n: int = 500) -> list[SampleBlock]:
    out = []
    for k in range(n_blocks):
        t = (start + k * n + np.arange(n)) / FS
        ch = {"current_A": 0.7 * np.sin(2 * np.pi * freq * t), "force_N": 175 + 45 * np.sin(2 * np.pi * freq * t),
              "flux_Wb": 5e-5 * np.sin(2 * np.pi * freq * t)}
        out.append(SampleBlock(start + k * n, FS, ch, meta=operating_meta(freq, 1.4, 0.0, True)))
    return out


def test_estimate_on_a_log_of_three_segments_names_segment_and_lists_them(tmp_path: Path, capsys):
    log = tmp_path / "sweep.mcap"
    with McapRecorder(log, metadata={"recording": META}) as rec:
        for b in _blocks(320.0, 0) + _blocks(160.0, 2000) + _blocks(80.0, 4000):
            rec.add_block(b)
    code = main(["estimate", str(log)])
    lines = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
    assert code == 2 and len(lines) == 1, lines
    line = lines[0]
    assert line.startswith("hystbench estimate: error: ") and "3 segments" in line
    assert "--segment" in line
    for k, f in enumerate(("320 Hz", "160 Hz", "80 Hz")):
        assert f"{k}: {f}/1.4 A-pp" in line, line
