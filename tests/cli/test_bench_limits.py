"""``python -m benchmarks limits``: which days it diagnoses, from the null days' limits, and how it counts
them (the sweep itself runs in .ci/run; its figures are in docs/diagnosis.md)."""

from __future__ import annotations

import pytest

from benchmarks.bench_diagnose import _reach
from benchmarks.bench_limits import markdown, summary, sweeps
from hystbench.analysis.diagnosis.columns import PROBES
from hystbench.analysis.diagnosis.limits import _limit


def _lim(value, at_most=False, in_range=True):
    return {"value": value, "unit": "s", "at_most": at_most, "either_sign": False, "in_range": in_range, "note": ""}


def test_each_limit_in_range_is_played_at_half_and_twice_its_size():
    nulls = {"ours": {"limits": {"channel_skew": {"flux_Wb": _lim(4e-7)},
                                 "charge_amp_highpass": {"time_constant_s": _lim(40.0, at_most=True)},
                                 "load_cell_compliance": {"stiffness_n_per_m": _lim(0.0, at_most=True, in_range=False)}}},
             "independent": {"limits": {"channel_skew": {"current_A": _lim(6e-8)}}}}
    days = sweeps(nulls)
    assert ("ours", "channel_skew", "flux_Wb", 0.5, pytest.approx(2e-7)) in days
    assert ("ours", "channel_skew", "flux_Wb", 2.0, pytest.approx(8e-7)) in days
    # a time constant's size is its inverse: twice the size is half the time constant
    assert ("ours", "charge_amp_highpass", "time_constant_s", 2.0, pytest.approx(20.0)) in days
    assert ("ours", "charge_amp_highpass", "time_constant_s", 0.5, pytest.approx(80.0)) in days
    assert not [d for d in days if d[1] == "load_cell_compliance"]  # no size the catalogue allows: not played
    assert [d[1:3] for d in days if d[0] == "independent"] == [("channel_skew", "current_A")] * 2


def _row(factor, score, named, decided):
    return {"suite": "ours", "effect": "channel_skew", "param": "flux_Wb", "factor": factor, "value": 1e-7,
            "limit": _lim(4e-7), "score": score, "decided": decided, "named": named}


def test_a_day_whose_effect_was_not_scored_is_not_counted_as_undecided():
    table = [_row(0.5, -3.0, False, False), _row(2.0, 60.0, True, True),
             _row(0.5, None, False, None), _row(2.0, None, False, None)]
    summ = summary(table)
    assert summ["decisive at 2x"] == "1/2" and summ["undecided at 0.5x"] == "1/2" and summ["not scored"] == "2"
    assert "| ours | channel_skew flux_Wb | >= 4e-07 s | -3.0 | 60.0 (decisive) | no / yes |" in markdown(table[:2], summ)


def test_a_miss_says_whether_its_true_size_was_within_the_days_reach():
    skew = _limit("channel_skew", "current_A", 7.3e-7, PROBES["channel_skew"][0])
    assert _reach(skew, {"current_A": 5e-7}) == "current_A >= 7.3e-07 s (true 5e-07: below the day's reach)"
    assert _reach(skew, {"current_A": 1e-6}) == "current_A >= 7.3e-07 s (true 1e-06: within the day's reach)"
    highpass, = PROBES["charge_amp_highpass"]
    tau = _limit("charge_amp_highpass", "time_constant_s", 1 / 44.0, highpass)
    assert _reach(tau, {"time_constant_s": 2.0}).endswith("(true 2: within the day's reach)")
    assert _reach(tau, {"tau_s": 2.0}) == "time_constant_s <= 44 s"  # another bench's name: no comparison
