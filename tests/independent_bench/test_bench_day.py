"""A bench day of the independent bench is one folder in the recording format, read back by
hystbench's own reader (the tests may import hystbench; the bench may not)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from hystbench.formats.recording import read_recording, read_sweep
from independent_bench import BASELINE, bench_day_plan, shuffled_blocks, write_bench_day


@pytest.fixture(scope="module")
def day(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, list[Path]]:
    folder = tmp_path_factory.mktemp("bench_day")
    effects = {**BASELINE, "force_offset_drift": True, "mains_pickup": True}
    return folder, write_bench_day(folder, effects=effects, seed=11, periods=12)


def test_a_shuffled_day_plays_each_block_whole_in_another_order():
    plan = bench_day_plan()
    blocks = lambda p: [(r, i) for k, (r, _, i) in enumerate(p) if k == 0 or p[k - 1][::2] != (r, i)]  # noqa: E731
    for seed in (1, 2):
        day = shuffled_blocks(plan, seed)
        assert blocks(day) == blocks(plan)  # the rigs and currents in the day's order
        for r, i in blocks(plan):
            played = [f for rr, f, ii in day if (rr, ii) == (r, i)]
            assert sorted(played) == sorted(f for rr, f, ii in plan if (rr, ii) == (r, i))
            assert played != sorted(played)  # 5 or 9 frequencies: another order than the ascending one
    assert shuffled_blocks(plan, 1) == shuffled_blocks(plan, 1) != shuffled_blocks(plan, 2)


def test_plan_is_the_issues_day():
    plan = bench_day_plan()
    assert {r for r, _, _ in plan} == {"voicecoil_ferrite", "ecore", "ecore_pm"}
    vc = [f for r, f, _ in plan if r == "voicecoil_ferrite"]
    assert min(vc) == 40.0 and max(vc) == 3000.0
    assert sorted({i for r, _, i in plan if r == "ecore_pm"}) == [0.7, 1.4]
    assert {i for r, _, i in plan if r == "ecore"} == {1.27}
    assert {f for r, f, _ in plan if r != "voicecoil_ferrite"} == {40.0, 80.0, 160.0, 320.0, 480.0}


def test_every_recording_reads_back_with_hystbenchs_reader(day):
    folder, stems = day
    recs = [read_recording(s) for s in stems]
    assert len(recs) == len(bench_day_plan())
    assert {r.rig for r in recs} == {"voicecoil_ferrite", "ecore", "ecore_pm"}
    for r in recs:
        assert r.fs_hz == 100e3
        assert {"current_A", "force_N", "command_V"} <= set(r.channels)
        assert ("flux_Wb" in r.channels) == (r.rig != "voicecoil_ferrite")
        assert r.n == round(12 * 100e3 / r.frequency_hz)
    starts = [r.start_time_s for r in recs]
    assert all(b > a for a, b in zip(starts, starts[1:]))  # one clock through the day
    pm = [r for r in recs if r.rig == "ecore_pm" and r.current_pp_a == 1.4]
    assert all(110 < float(np.mean(r.channels["force_N"])) < 200 for r in pm)


def test_sidecars_hold_what_a_real_bench_writes(day):
    folder, _ = day
    for path in folder.glob("*.json"):
        side = json.loads(path.read_text())
        assert {"rig", "frequency_Hz", "sample_rate_Hz", "current_pp_A", "start_time_s"} <= set(side)
        assert "effects" not in side and "seed" not in side
        if side["rig"] != "voicecoil_ferrite":
            assert side["sense_turns"] == 10


def test_the_folder_is_one_sweep_of_several_rigs(day):
    """recording-format.md: a bench day's sweep may hold several rigs, told apart by the sidecar;
    read_sweep returns them all, each rig's recordings together."""
    folder, stems = day
    recs = read_sweep(folder)
    assert len(recs) == len(stems) == len(bench_day_plan())
    assert {r.rig for r in recs} == {"voicecoil_ferrite", "ecore", "ecore_pm"}
    keys = [(r.rig, r.frequency_hz, r.current_pp_a) for r in recs]
    assert keys == sorted(keys)
