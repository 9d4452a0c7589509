"""Issue 30, item 6: a clipped simulated recording is refused with advice that matches the cause:
the noise (lower the noise or raise the full scale; the current is not to blame) or the signal
(lower --ipp or raise the full scale)."""

from __future__ import annotations

from pathlib import Path

from hystbench.cli.main import main

BASE = ["simulate", "--rig", "voicecoil_ferrite", "--freq", "320", "--ipp", "1", "--duration", "0.02"]


def refusal(tmp_path: Path, capsys, *effects: str) -> str:
    args = BASE + ["--out", str(tmp_path / "run")] + [a for e in effects for a in ("--effect", e)]
    code = main(args)
    lines = [ln for ln in capsys.readouterr().err.splitlines() if ": error: " in ln]
    assert code == 2 and len(lines) == 1, lines
    assert list(tmp_path.iterdir()) == []  # refused before anything was written
    return lines[0]


def test_noise_that_clips_is_named_and_the_current_is_not_blamed(tmp_path: Path, capsys):
    # 1 A-pp is 0.5 A peak, a quarter of the 2 A full scale; noise of 0.5 A rms reaches it
    line = refusal(tmp_path, capsys, "sensor_noise.current_a=0.5")
    assert "current_A" in line and "noise" in line
    assert "--effect sensor_noise.current_a=" in line
    assert "--ipp" not in line


def test_a_current_beyond_the_full_scale_is_told_to_lower_ipp(tmp_path: Path, capsys):
    # 0.5 A peak against a 0.45 A full scale, with the preset's small noise
    line = refusal(tmp_path, capsys, "adc_quantisation.current_a=0.45")
    assert "current_A" in line and "lower --ipp" in line
    assert "adc_quantisation.current_a=" in line
    assert "sensor_noise" not in line
