"""A simulated bench day: one running rig per rig type, every recording's start on the day's one
clock, the instrument's slow drift running on across the rigs, a foreign bench's two E-cores on one
core, and sidecars without the generator's truth."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from hystbench.cli.main import main
from hystbench.config import load_rig
from hystbench.errors import ConfigError
from hystbench.formats.recording import read_sweep, write_sweep
from hystbench.sim_backend.bench_day import (BenchDayPlan, RigBlock, bench_effects, bench_presets, public_metadata,
                                             simulate_bench_day)
from hystbench.sim_backend.benches import FOREIGN_BENCHES

FS = 100_000.0
GAP = 0.1
#: A short day: two points per rig, 8 periods each (the structure of issue 13's day, not its length).
SHORT = BenchDayPlan((RigBlock.grid("voicecoil_ferrite", (200.0, 1000.0), [1.0], periods=8.0, min_duration_s=0.02),
                      RigBlock.grid("ecore", (80.0, 320.0), [1.27], periods=8.0),
                      RigBlock("ecore_pm", ((80.0, 0.7), (320.0, 1.4)), periods=8.0)), gap_s=GAP)


def _settle_samples(f: float) -> int:
    return round(max(5.0 / f, 0.02) * FS)  # the plan's settling: 5 periods, at least 20 ms


def test_start_times_follow_the_plan_on_one_clock() -> None:
    """Within a rig: the next start is the previous one + its samples + the settling before the next
    point; between rigs: the gap plus the new rig's settling before its first point."""
    recs = simulate_bench_day(SHORT, seed=3)
    assert [(r.rig, r.frequency_hz, r.current_pp_a) for r in recs] == [
        ("voicecoil_ferrite", 200.0, 1.0), ("voicecoil_ferrite", 1000.0, 1.0), ("ecore", 80.0, 1.27),
        ("ecore", 320.0, 1.27), ("ecore_pm", 80.0, 0.7), ("ecore_pm", 320.0, 1.4)]
    assert [r.n for r in recs] == [4000, 2000, 10_000, 2500, 10_000, 2500]  # 8 periods, or 20 ms
    starts = [r.start_time_s for r in recs]
    assert starts[0] == pytest.approx(_settle_samples(200.0) / FS, abs=1e-12)  # the day begins with the first settling
    for k in range(1, len(recs)):
        prev, rec = recs[k - 1], recs[k]
        expect = starts[k - 1] + prev.n / FS + _settle_samples(rec.frequency_hz) / FS
        if rec.rig != prev.rig:
            expect += GAP
        assert starts[k] == pytest.approx(expect, abs=1e-9), k
    assert all(b > a for a, b in zip(starts, starts[1:]))


def test_force_offset_drift_runs_on_the_days_clock_across_the_rigs() -> None:
    """One charge amplifier drifting 1 N/s: each record's mean force, less that of the same day
    without the drift (same seed: same noise), is 1 N/s times the record's mid-time on the day's
    clock, on every rig: one line through 0, no restart when a rig starts."""
    drift = bench_effects({"force_offset_drift": {"offset_n": 0.0, "drift_n_per_s": 1.0}})
    with_drift = simulate_bench_day(SHORT, seed=5, effects=drift)
    without = simulate_bench_day(SHORT, seed=5)
    assert not any(r.metadata.get("clipped") for r in with_drift)
    mid = np.array([r.start_time_s + (r.n - 1) / 2 / FS for r in with_drift])
    shift = np.array([np.mean(a.channels["force_N"] - b.channels["force_N"]) for a, b in zip(with_drift, without)])
    assert mid[-1] > 0.6  # the day is long enough for the drift to matter (> 40 LSB of the ecore's ADC)
    np.testing.assert_allclose(shift, 1.0 * mid, atol=2e-3)
    # the slope over the whole day, by least squares
    slope, intercept = np.polyfit(mid, shift, 1)
    assert slope == pytest.approx(1.0, abs=3e-3) and intercept == pytest.approx(0.0, abs=2e-3)


def test_sidecars_hold_no_generator_truth_unless_asked(tmp_path: Path) -> None:
    recs = simulate_bench_day(SHORT, seed=1, effects={"ecore_pm": {"magnet_thermal_drift": True}})
    for r in recs:
        assert not {"effects", "seed", "generator_frequency_Hz"} & set(r.metadata)
        assert r.start_time_s is not None and r.metadata["sample_rate_Hz"] == FS
    truth = simulate_bench_day(SHORT, seed=1, truth_in_sidecar=True,
                               effects={"ecore_pm": {"magnet_thermal_drift": True}})
    assert "magnet_thermal_drift" in truth[-1].metadata["effects"] and "seed" in truth[0].metadata
    assert "magnet_thermal_drift" not in truth[2].metadata["effects"]  # the ecore rig has no magnet
    assert public_metadata(truth[0].metadata) == recs[0].metadata
    for rig in SHORT.rigs:  # each rig's part is a sweep folder that reads back with its starts
        mine = [r for r in recs if r.rig == rig]
        write_sweep(mine, tmp_path / rig)
        back = read_sweep(tmp_path / rig)
        assert sorted(r.start_time_s for r in back) == sorted(r.start_time_s for r in mine)
        assert not any("effects" in json.loads(p.read_text()) for p in (tmp_path / rig).glob("*.json"))


def test_recordings_as_short_as_a_tenth_of_a_second() -> None:
    plan = BenchDayPlan((RigBlock.grid("ecore_pm", (40.0, 320.0), [1.4], periods=0.0, min_duration_s=0.1),))
    recs = simulate_bench_day(plan)
    assert [r.n for r in recs] == [10_000, 10_000] and [r.duration_s for r in recs] == [0.1, 0.1]
    assert recs[1].start_time_s - recs[0].start_time_s == pytest.approx(0.1 + 0.02, abs=1e-12)


def test_a_foreign_bench_has_one_core_for_both_e_cores() -> None:
    """Both E-cores of a foreign bench carry its declared factors on the nominal geometry, one iron,
    one coil and one instrument; the voice coil sits on the same load cell."""
    name = "ecore_pm~m130"
    declared = FOREIGN_BENCHES[name]
    presets = bench_presets(name)
    ecore, ecore_pm, coil = presets["ecore"], presets["ecore_pm"], presets["voicecoil_ferrite"]
    nominal = load_rig("ecore")
    for key, factor in declared.geometry.items():
        assert ecore["geometry"][key] == pytest.approx(nominal["geometry"][key] * factor, rel=1e-12)
    assert ecore["geometry"] == ecore_pm["geometry"]
    assert ecore["iron"]["material"] == ecore_pm["iron"]["material"] == "M130-27S"
    assert ecore["coil"] == ecore_pm["coil"] and ecore["coil"]["turns"] == round(146 * declared.turns)
    assert ecore["instrument"] == ecore_pm["instrument"] == coil["instrument"]
    assert ecore["instrument"]["fn_hz"] == pytest.approx(4450.0 * declared.instrument["fn_hz"])
    assert "magnet" not in ecore and ecore_pm["magnet"]["remanence_t"] == pytest.approx(1.2 * declared.remanence)
    assert (ecore["name"], ecore_pm["name"], coil["name"]) == ("ecore", "ecore_pm", "voicecoil_ferrite")
    recs = simulate_bench_day(SHORT, bench=name, seed=2)
    assert [r.rig for r in recs] == [r for r in SHORT.rigs for _ in range(2)]  # the nominal names, nothing else
    assert all(set(r.metadata) <= {"rig", "frequency_Hz", "sample_rate_Hz", "current_pp_A", "offset_A", "source",
                                   "sense_turns", "start_time_s"} for r in recs)
    nominal_day = simulate_bench_day(SHORT, seed=2)  # and the bench's iron is not the nominal's
    flux = [np.ptp(r.channels["flux_Wb"]) for r in recs[2:]]
    assert not np.allclose(flux, [np.ptp(r.channels["flux_Wb"]) for r in nominal_day[2:]], rtol=0.02)


def test_bench_effects_go_to_the_rigs_they_act_on() -> None:
    out = bench_effects({"charge_amp_highpass": {"time_constant_s": 2.0}, "integrator_leak": 0.5,
                         "magnet_thermal_drift": True, "lamination_eddy_currents": False,
                         "channel_skew": {"flux_Wb": 1e-6}, "mains_pickup": True})
    assert set(out["voicecoil_ferrite"]) == {"charge_amp_highpass", "mains_pickup"}
    assert set(out["ecore"]) == {"charge_amp_highpass", "integrator_leak", "lamination_eddy_currents",
                                 "channel_skew", "mains_pickup"}
    assert set(out["ecore_pm"]) == set(out["ecore"]) | {"magnet_thermal_drift"}
    assert out["ecore"]["lamination_eddy_currents"] is False
    with pytest.raises(ConfigError, match="unknown effect 'warp_drive'"):
        bench_effects({"warp_drive": True})


def test_bad_plans_and_effects_are_refused_naming_what() -> None:
    with pytest.raises(ConfigError, match="effects for rig toroid"):
        simulate_bench_day(SHORT, effects={"toroid": {"sensor_noise": False}})
    with pytest.raises(ConfigError, match="one block per rig"):
        BenchDayPlan((RigBlock("ecore", ((80.0, 1.0),)), RigBlock("ecore", ((320.0, 1.0),))))
    with pytest.raises(ConfigError, match="rig ecore: frequency 60000.0 Hz"):
        BenchDayPlan((RigBlock("ecore", ((60_000.0, 1.0),)),))
    with pytest.raises(ConfigError, match="unknown foreign bench 'nowhere'"):
        simulate_bench_day(SHORT, bench="nowhere")


def test_the_default_plan_is_issue_13s_day() -> None:
    plan = BenchDayPlan()
    assert plan.rigs == ("voicecoil_ferrite", "ecore", "ecore_pm")
    vc, ecore, ecore_pm = plan.blocks
    freqs = [f for f, _ in vc.points]
    assert len(freqs) == 12 and freqs[0] == 10.0 and 3900 <= freqs[-1] <= 4100 and vc.fs_hz == FS
    assert np.allclose(np.diff(np.log(freqs)), math.log(400) / 11, rtol=0.01)  # log-spaced
    assert all(i == 1.0 for _, i in vc.points) and vc.samples(4000.0) == 2000 and vc.samples(10.0) == 200_000
    assert ecore.points == tuple((f, 1.27) for f in (40.0, 80.0, 160.0, 320.0, 480.0))
    assert ecore_pm.points == tuple((f, i) for i in (0.7, 1.4) for f in (40.0, 80.0, 160.0, 320.0, 480.0))
    assert ecore.samples(480.0) == 10_000 and ecore_pm.samples(40.0) == 120_000  # 48 periods


def test_simulate_sweep_keeps_one_rig_running(tmp_path: Path) -> None:
    """A drift of 100 N/s on the voice coil's force: each recording's mean force is 100 N/s times its
    mid-time on the sweep's clock, which goes on from one point to the next (a fresh rig per point
    would restart it at 0)."""
    out = tmp_path / "sweep"
    assert main(["simulate-sweep", "--rig", "voicecoil_ferrite", "--freqs", "40,320", "--duration", "0.05",
                 "--effect", "force_offset_drift.drift_n_per_s=100", "--effect", "force_offset_drift.offset_n=0",
                 "--effect", "sensor_noise=off", "--out", str(out)]) == 0
    recs = read_sweep(out)
    assert [r.start_time_s for r in recs] == pytest.approx([0.125, 0.125 + 0.05 + 0.02], abs=1e-12)
    for r in recs:  # whole periods of the sine average to ~0: what is left is the drift
        assert np.mean(r.channels["force_N"]) == pytest.approx(100.0 * (r.start_time_s + 0.025), abs=0.02)


def test_simulate_bench_day_writes_one_sweep_per_rig_and_refuses_before_writing(tmp_path: Path, capsys) -> None:
    out = tmp_path / "day"
    assert main(["simulate-bench-day", str(out), "--quick", "--seed", "4", "--effect", "ecore_pm:mains_pickup=on",
                 "--effect", "force_offset_drift=0.01"]) == 0
    printed = capsys.readouterr().out
    sweeps = {rig: read_sweep(out / rig) for rig in ("voicecoil_ferrite", "ecore", "ecore_pm")}
    assert all(str(out / rig) in printed for rig in sweeps)
    assert [len(s) for s in sweeps.values()] == [4, 2, 4]
    ends = [(min(r.start_time_s for r in s), max(r.start_time_s for r in s)) for s in sweeps.values()]
    assert ends[0][1] < ends[1][0] and ends[1][1] < ends[2][0]  # the rigs one after another
    assert not any("effects" in r.metadata or "seed" in r.metadata for s in sweeps.values() for r in s)
    before = sorted(p.name for p in out.rglob("*"))
    assert main(["simulate-bench-day", str(out), "--quick"]) == 2  # exists: refused, nothing rewritten
    assert "exists; give --overwrite" in capsys.readouterr().err
    other = tmp_path / "other"
    assert main(["simulate-bench-day", str(other), "--quick", "--effect", "toroid:sensor_noise=off"]) == 2
    assert "no rig 'toroid'" in capsys.readouterr().err and not other.exists()
    assert main(["simulate-bench-day", str(other), "--quick", "--bench", "nowhere"]) == 2
    assert "unknown foreign bench" in capsys.readouterr().err and not other.exists()
    assert sorted(p.name for p in out.rglob("*")) == before
