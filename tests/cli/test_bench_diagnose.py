"""``python -m benchmarks diagnose``: the targets and the confusion table judge the diagnosis's answers
against the generator's truth as the issue states them; an unknown case is refused naming it."""

from __future__ import annotations

import math

import pytest

from types import SimpleNamespace

from benchmarks.bench_diagnose import confusion, targets, why_wrong
from hystbench.analysis.diagnosis.result import Candidate
from benchmarks.__main__ import main


def _row(case, truth, named, signature, seconds=5.0):
    """A row as the benchmark writes it; ``signature``: each named true effect's held-out improvement
    in its own signature."""
    right = (not named) if not truth else (named[0] in truth and set(truth) <= set(named))
    return {"case": case, "truth": truth, "named": named, "right": right,
            "signature": {e: signature for e in named if e in truth}, "seconds_diagnose": seconds}


ROWS = [_row("a", ["charge_amp_highpass"], ["charge_amp_highpass"], 30.0),
        _row("b", ["channel_skew"], ["lamination_eddy_currents"], None, seconds=40.0),
        _row("c", ["force_offset_drift", "mains_pickup"], ["mains_pickup", "force_offset_drift"], 8.0, seconds=40.0),
        _row("d", ["charge_amp_highpass", "channel_skew"], ["charge_amp_highpass"], 1.2, seconds=40.0),  # one of two
        _row("n1", [], [], None), _row("n2", [], ["iron_saturation"], None, seconds=61.0),
        _row("n3", [], [], None, seconds=62.0)]


def test_the_targets_pass_and_fail_as_the_issue_states_them():
    named, improvement, null, speed = targets(ROWS)
    assert named["measured"].startswith("50 %") and named["pass"] is False  # a and c of 4: d names one of two
    assert improvement["pass"] is False and "worst 1.20x" in improvement["measured"]  # b: none named, d: 1.2x
    assert null["measured"] == "2/3" and null["pass"] is False
    assert speed["pass"] is False and "median 40.0" in speed["measured"]  # 5, 5, 40, 40, 40, 61, 62
    good = [r for r in ROWS if r["case"] in ("a", "c", "n1")]
    assert all(t["pass"] for t in targets(good))


def test_the_confusion_table_counts_truth_against_named():
    conf = confusion(ROWS)
    assert conf["charge_amp_highpass"] == {"charge_amp_highpass": 1}
    assert conf["channel_skew"] == {"lamination_eddy_currents": 1}
    assert conf["charge_amp_highpass+channel_skew"] == {"charge_amp_highpass": 1}
    assert conf["none"] == {"none": 2, "iron_saturation": 1}


def test_an_unknown_case_is_refused_naming_it(capsys):
    with pytest.raises(SystemExit) as stop:
        main(["diagnose", "--cases", "null_seed1,no_such_case"])
    assert stop.value.code == 2
    err = capsys.readouterr().err
    assert "--cases" in err and "no_such_case" in err and "null_seed1" in err


def test_another_copy_is_refused_for_our_suite_saying_which_has_one(capsys):
    with pytest.raises(SystemExit) as stop:
        main(["diagnose", "--suite", "all", "--another-copy"])
    assert stop.value.code == 2
    err = capsys.readouterr().err
    assert "--another-copy" in err and "--suite independent" in err


@pytest.mark.parametrize("argv, says", [(["--suite", "ours", "--drawn-copy", "3"], ["--drawn-copy", "--suite independent"]),
                                        (["--suite", "independent", "--drawn-copy", "-1"], ["--drawn-copy", "a seed is >= 0"]),
                                        (["--suite", "independent", "--another-copy", "--drawn-copy", "3"],
                                         ["--another-copy", "--drawn-copy", "one copy"])])
def test_a_drawn_copy_is_refused_where_it_cannot_be_played(capsys, argv, says):
    with pytest.raises(SystemExit) as stop:
        main(["diagnose", *argv])
    assert stop.value.code == 2
    err = capsys.readouterr().err
    assert all(s in err for s in says), err


def test_a_worker_plays_the_day_on_the_copy_it_is_asked_for(monkeypatch):
    import benchmarks.bench_diagnose as bench

    played = []
    monkeypatch.setattr(bench, "run_independent_case",
                        lambda case, out=None, say=None, shuffle=None, another_copy=False, draw=None: played.append(
                            (case.name, another_copy, draw)) or {})
    bench.run_named("null_seed1", suite="independent", another_copy=True)
    bench.run_named("null_seed1", suite="independent")
    bench.run_named("null_seed1", suite="independent", draw=4)
    assert played == [("null_seed1", True, None), ("null_seed1", False, None), ("null_seed1", False, 4)]
    with pytest.raises(ValueError, match="another_copy"):
        bench.run_named("null_seed1", suite="ours", draw=4)
    with pytest.raises(ValueError, match="another_copy"):
        bench.run_named("null_seed1", suite="ours", another_copy=True)


def _answer(named, candidates, suspects=(), signature=None):
    """A diagnosis's answer as why_wrong reads it: the names, every candidate's (name, score) and the
    suspects' (name, score, held-out gain)."""
    return SimpleNamespace(effects=list(named), candidates=[Candidate(n, s, {}) for n, s in candidates], limits=[],
                           suspects=[Candidate(n, s, {}, held_out_gain=g) for n, s, g in suspects],
                           signature=signature or {})


def test_why_wrong_tells_a_miss_below_the_data_from_one_outranked_or_refused():
    below = _answer([], [("load_cell_compliance", -4.0), ("frame_resonance", -7.0)])
    assert why_wrong(["load_cell_compliance"], below) == [
        "load_cell_compliance: below the data's decision (best score -4.0 < 10)"]
    outranked = _answer(["magnet_eddy_currents"], [("magnet_eddy_currents", 41.7), ("channel_skew", 26.7)],
                        signature={"magnet_eddy_currents": {"improvement": 1.6}})
    assert why_wrong(["channel_skew"], outranked) == [
        "channel_skew: score 27, outranked by magnet_eddy_currents",
        "magnet_eddy_currents: named, not in the truth (held out 1.60x in its signature)"]
    undecided = _answer([], [("magnet_thermal_drift", 33.6), ("load_cell_compliance", 32.1), ("channel_skew", 24.6)])
    assert why_wrong(["magnet_thermal_drift"], undecided) == [
        "magnet_thermal_drift: score 34, undecided against load_cell_compliance 32 (within 6)"]
    assert why_wrong(["magnet_thermal_drift"], _answer([], [("magnet_thermal_drift", 33.6)])) == [
        "magnet_thermal_drift: score 34, first in round 1 and not named"]
    refused = _answer([], [("channel_skew", 1558.0)], suspects=[("channel_skew", 1558.0, 1.45)])
    assert why_wrong(["channel_skew"], refused) == [
        "channel_skew: refused by the held-out proof (1.45x at the median fold, score 1558)"]
    broken = _answer([], [("frame_resonance", 900.0)], suspects=[("frame_resonance", 900.0, 1.7)])
    broken.suspects[0] = Candidate("frame_resonance", 900.0, {}, held_out_gain=1.7, held_out_total=0.004)
    assert why_wrong(["frame_resonance"], broken) == [
        "frame_resonance: refused by the held-out proof (1.70x at the median fold, 0.004x in total, score 900)"]
    untested = _answer([], [("charge_amp_highpass", 9750.0)], suspects=[("charge_amp_highpass", 9750.0, math.nan)])
    assert why_wrong(["charge_amp_highpass"], untested) == [
        "charge_amp_highpass: refused by the held-out proof (it moves no held-out number by half a sigma, score 9750)"]
    right = _answer(["integrator_leak"], [("integrator_leak", 300.0)])
    assert why_wrong(["integrator_leak"], right) == [] and why_wrong([], _answer([], [])) == []


def test_why_wrong_says_how_much_of_a_missed_effect_the_baseline_could_not_do():
    """A miss whose candidate was measured against the baseline's span says so: a compliance is a
    smaller airgap but for a millionth of it."""
    below = SimpleNamespace(effects=[], suspects=[], signature={}, limits=[], candidates=[Candidate(
        "load_cell_compliance", -4.0, {}, mimicry={"own": 1.5e-6, "the calibration's knobs": 0.998})])
    assert why_wrong(["load_cell_compliance"], below) == [
        "load_cell_compliance: below the data's decision (best score -4.0 < 10) (of what it does, "
        "1.5e-06 its own, 99.8 % within the calibration's knobs)"]


def test_markdown_marks_a_wrong_name_and_says_why():
    rows = [dict(r, suite="ours", suspects=[], residual_before=2.0, residual_after=1.0,
                 why=[] if r["right"] else ["a reason"]) for r in ROWS]
    from benchmarks.bench_diagnose import judge, markdown

    text = markdown({"cases": rows, "suites": judge(rows)})
    assert "| channel_skew | **lamination_eddy_currents** | 1 |" in text
    assert "| charge_amp_highpass | charge_amp_highpass | 1 |" in text
    assert "| b | a reason |" in text and "| a | a reason |" not in text
    assert "50 % (2/4) | FAIL |" in text


def test_the_tables_of_the_copy_say_which_bench_they_are_of():
    rows = [dict(r, suite="independent", suspects=[], residual_before=2.0, residual_after=1.0,
                 why=[] if r["right"] else ["a reason"]) for r in ROWS]
    from benchmarks.bench_diagnose import judge, markdown

    first = markdown({"cases": rows, "suites": judge(rows)})
    copy = markdown({"cases": rows, "suites": judge(rows), "another_copy": True})
    assert "#### independent (7 days)" in first and "another copy" not in first
    assert "#### independent (another copy of its bench) (7 days)" in copy
