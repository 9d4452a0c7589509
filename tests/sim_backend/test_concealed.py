"""The concealed-effect suite (hystbench/sim_backend/concealed.py): it covers every effect a baseline can
lack, nulls and foreign benches as issue 13 asks, each case simulates, its truth reaches the data and
never the sidecars."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from hystbench.config import load_rig
from hystbench.config.effects import CATALOGUE
from hystbench.sim_backend.bench_day import BENCH_DAY_RIGS, TRUTH_KEYS, BenchDayPlan, RigBlock
from hystbench.sim_backend.benches import FOREIGN_BENCHES
from hystbench.sim_backend.concealed import CASES, DIAGNOSED_DIRECTLY, PRESET_BASELINE, simulate_case

BY_NAME = {c.name: c for c in CASES}
QUICK = BenchDayPlan.quick()


def _preset_effects(rig: str) -> set[str]:
    return set(load_rig(rig)["effects"])


def test_every_effect_a_baseline_can_lack_is_some_case_s_truth():
    named = {e for c in CASES for e in c.truth}
    assert set(CATALOGUE) - set(DIAGNOSED_DIRECTLY) <= named, sorted(set(CATALOGUE) - named)
    assert set(PRESET_BASELINE) == set().union(*(_preset_effects(r) for r in BENCH_DAY_RIGS))


def test_the_suite_has_two_effect_cases_nulls_and_foreign_benches():
    assert sum(len(c.truth) == 2 for c in CASES) >= 2
    nulls = [c for c in CASES if c.null]
    assert len({c.seed for c in nulls if c.bench is None and not c.preset_factors}) >= 3
    assert any(c.preset_factors for c in nulls)
    foreign = [c for c in CASES if c.bench is not None]
    assert {c.bench for c in foreign if c.null} >= {"ecore_pm~m130", "ecore_pm~elliptic", "ecore_pm~rayleigh"}
    assert len([c for c in foreign if not c.null]) >= 3
    assert all(c.bench in FOREIGN_BENCHES for c in foreign)
    assert len({(c.seed, c.bench) for c in CASES}) == len(CASES)  # no two days alike but for the effect


@pytest.mark.parametrize("c", CASES, ids=lambda c: c.name)
def test_the_truth_is_in_the_data_and_not_in_the_baseline(c):
    for e in c.truth:
        in_data = [r for r in BENCH_DAY_RIGS if e in c.effects.get(r, {}) or e in _preset_effects(r)]
        assert in_data, f"{e} reaches no rig"
        if c.baseline is None:  # the presets' effects are the baseline: the truth is on no preset
            assert not any(e in _preset_effects(r) for r in BENCH_DAY_RIGS)
        else:
            assert e not in c.baseline
    if c.baseline is not None:  # an explicit baseline is true of the data but for the truth: one frame for all
        data = {r: _preset_effects(r) | set(c.effects.get(r, {})) for r in BENCH_DAY_RIGS}
        assert all("frame_resonance" in have for have in data.values())
        assert set(c.baseline) <= set().union(*data.values())

def test_bench_wide_effects_reach_every_rig_they_act_on():
    hp = BY_NAME["charge_amp_highpass"].effects
    assert all(hp[r]["charge_amp_highpass"]["time_constant_s"] == 2.0 for r in BENCH_DAY_RIGS)  # all have force
    leak = BY_NAME["integrator_leak"].effects
    assert "integrator_leak" not in leak["voicecoil_ferrite"] and all(
        "integrator_leak" in leak[r] for r in ("ecore", "ecore_pm"))  # the coil has no flux channel
    thermal = BY_NAME["magnet_thermal_drift"].effects
    assert [r for r in BENCH_DAY_RIGS if "magnet_thermal_drift" in thermal[r]] == ["ecore_pm"]
    skew = BY_NAME["channel_skew_flux"].expected["channel_skew"]
    assert skew["flux_Wb"] == 3e-6 and skew["force_N"] == 0.0 and skew["current_A"] == 0.0  # not the defaults


@pytest.mark.parametrize("c", CASES, ids=lambda c: c.name)
def test_each_case_simulates_and_its_sidecars_hold_no_truth(c):
    recs = simulate_case(c, plan=QUICK)
    points = [(b.rig, f, i) for b in QUICK.blocks for f, i in b.points]
    assert [(r.rig, r.frequency_hz, r.current_pp_a) for r in recs] == points
    starts = [r.start_time_s for r in recs]
    assert all(b > a for a, b in zip(starts, starts[1:]))
    for r in recs:
        assert not set(TRUTH_KEYS) & set(r.metadata)
        text = json.dumps(r.metadata)
        assert not [e for e in CATALOGUE if e in text], text
        assert all(np.isfinite(x).all() for x in r.channels.values())


def _ecore_day(seed: int) -> BenchDayPlan:
    return BenchDayPlan((RigBlock.grid("ecore", (80.0, 320.0), [1.27], periods=12.0),), gap_s=0.0)


def test_the_drift_case_adds_drift_times_the_day_s_clock_to_the_force():
    """Same day and noise with and without the case's effect: the mean force differs by
    drift x (the clock at the recording's middle), the charge amplifier's offset integrated from 0."""
    drift = BY_NAME["force_offset_drift"]
    null = dataclasses.replace(drift, truth=(), effects={}, expected={})
    plan = _ecore_day(drift.seed)
    with_, without = simulate_case(drift, plan=plan), simulate_case(null, plan=plan)
    rate = drift.expected["force_offset_drift"]["drift_n_per_s"]
    for a, b in zip(with_, without):
        t_mid = a.start_time_s + (a.n - 1) / (2 * a.fs_hz)
        assert np.mean(a.channels["force_N"] - b.channels["force_N"]) == pytest.approx(rate * t_mid, rel=1e-3)


def test_the_off_nominal_null_moves_the_load_cell_resonance_by_its_factor():
    """At 4 kHz, near the load cell's fn = 4450 Hz, a 3 % higher fn changes the force/current gain by
    |1 - r^2 + 2j zeta r| ratio (r = f/fn), the second-order section's own formula."""
    off = BY_NAME["null_off_nominal"]
    nominal = dataclasses.replace(off, preset_factors={})
    plan = BenchDayPlan((RigBlock.grid("voicecoil_ferrite", (4000.0,), [1.0], periods=40.0),))
    (a,), (b,) = simulate_case(off, plan=plan), simulate_case(nominal, plan=plan)

    def gain(rec):
        t = np.arange(rec.n) / rec.fs_hz
        e = np.exp(-2j * np.pi * rec.frequency_hz * t)
        return abs(rec.channels["force_N"] @ e) / abs(rec.channels["current_A"] @ e)

    inst = load_rig("voicecoil_ferrite")["instrument"]
    fn, zeta, f = inst["fn_hz"], inst["zeta_n"], 4000.0

    def section(fn_hz):
        r = f / fn_hz
        return 1.0 / abs(1 - r * r + 2j * zeta * r)

    expected = section(fn * off.preset_factors["voicecoil_ferrite"]["instrument.fn_hz"]) / section(fn)
    assert expected < 0.9  # the check can tell 3 % from nothing
    assert gain(a) / gain(b) == pytest.approx(expected, rel=0.01)
