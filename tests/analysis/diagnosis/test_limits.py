"""A bench day's decision limits (hystbench.analysis.diagnosis.limits): the size at which an effect's change,
beyond what the calibrated baseline absorbs with its priors, is expected to score the naming margin.

The sizes are checked against the closed form of generalised least squares (the normal equations,
written out here with numpy, not the diagnosis's solver) and against the score as forward selection
defines it (the baseline's fit minus the candidate's, less the charge); whether a limit says what a whole
diagnosis decides is ``python -m benchmarks limits``'s question (each limit at 0.5x and 2x on real days)."""

from __future__ import annotations

import dataclasses
import json
import math
from types import SimpleNamespace

import numpy as np
import pytest

from hystbench.analysis.diagnosis.calibrate import Calibration
from hystbench.analysis.diagnosis.columns import PROBES
from hystbench.analysis.diagnosis.fit import Column, Problem, solve
from hystbench.analysis.diagnosis.limits import _limit, detection_limits, seen_at, size_on_grid, unexplained
from hystbench.analysis.diagnosis.result import Diagnosis
from hystbench.analysis.diagnosis.select import NAME_MARGIN, CandidateEffect
from hystbench.analysis.diagnosis.vector import CHANNELS

SKEW = PROBES["channel_skew"][0]
HIGHPASS, = PROBES["charge_amp_highpass"]


def _problem(d: np.ndarray, sigma: np.ndarray, layout=None) -> Problem:
    n = d.size
    layout = layout or SimpleNamespace(size=n, channel=np.zeros(n, int), harmonic=np.ones(n, int))
    return Problem(d=d, sigma=sigma, rows=np.arange(n), model_many=lambda requests: [], layout=layout,
                   noise=sigma, line_records=np.zeros(0, int))


def _calibration(problem: Problem, columns: list[Column]) -> Calibration:
    m0 = np.zeros(problem.d.size)
    return Calibration([], columns, m0, {}, problem.solve(m0, columns), np.zeros((problem.d.size, 0)))


def _closed_form(u: np.ndarray, sigma: np.ndarray, columns: list[Column]) -> float:
    """min over beta of |(u - B beta) / sigma|^2 + sum (beta_i / prior_i)^2, by the normal equations."""
    W = np.diag(1 / sigma ** 2)
    B = np.column_stack([c.values for c in columns])
    P = np.diag([0.0 if c.prior is None else 1 / c.prior ** 2 for c in columns])
    return float(u @ W @ u - u @ W @ B @ np.linalg.solve(B.T @ W @ B + P, B.T @ W @ u))


def _score(problem: Problem, judge: Problem, residual: np.ndarray, base: list[Column], own: list[Column],
           charged: int) -> float:
    """The score forward selection gives: the baseline's fit on every row, the candidate's on its own."""
    b = solve(residual, problem.sigma, base, problem.rows)
    c = solve(residual, judge.sigma, base + own, judge.rows)
    return (b.chi2 + b.chi2_prior) - (c.chi2 + c.chi2_prior) - charged * math.log(problem.rows.size)


def test_what_the_baseline_leaves_unexplained_is_generalised_least_squares():
    rng = np.random.default_rng(7)
    n = 400
    sigma = rng.uniform(0.5, 2.0, n)
    base = [Column("knob", rng.normal(size=n), prior=0.3), Column("discrepancy", rng.normal(size=n), prior=2.0),
            Column("free", rng.normal(size=n))]
    change = 0.6 * base[0].values + 0.3 * base[2].values + rng.normal(size=n)  # partly a recalibration
    problem = _problem(np.zeros(n), sigma)
    assert unexplained(problem, change, base) == pytest.approx(_closed_form(change, sigma, base), rel=1e-6)


def test_at_its_limit_an_effect_scores_the_naming_margin():
    rng = np.random.default_rng(11)
    n = 300
    sigma = rng.uniform(0.5, 2.0, n)
    base = [Column("knob", rng.normal(size=n), prior=0.2), Column("free", rng.normal(size=n))]
    u = rng.normal(size=n) + 2.0 * base[0].values
    problem = _problem(np.zeros(n), sigma)
    effect = CandidateEffect("channel_skew@current_A", [Column("channel_skew@current_A.current_A", u)], (SKEW,))
    lim, = detection_limits(problem, {effect.name: effect}, _calibration(problem, base))
    assert (lim.effect, lim.param, lim.at_most, lim.either_sign) == ("channel_skew", "current_A", False, False)
    assert _score(problem, problem, lim.value * u, base, effect.columns, 1) == pytest.approx(NAME_MARGIN, rel=1e-6)


def test_a_dc_blind_effect_pays_for_the_dcs_it_frees_and_is_credited_what_the_baseline_misses_there():
    """The high-pass's score: the baseline on every row, the candidate without the force's DCs, each charged;
    here the day misses its four force DCs by 3 sigma each, and the effect moves only the harmonics."""
    rng = np.random.default_rng(5)
    n = 200
    force = CHANNELS.index("force_N")
    layout = SimpleNamespace(size=n, channel=np.full(n, force), harmonic=np.where(np.arange(n) < 4, 0, 1))
    sigma = np.ones(n)
    missed = np.where(layout.harmonic == 0, 3.0, 0.0)
    problem = _problem(missed, sigma, layout)
    base = [Column("knob", np.where(layout.harmonic == 0, 0.0, rng.normal(size=n)), prior=0.3)]
    u = np.where(layout.harmonic == 0, 0.0, rng.normal(size=n))
    tau = 4.0
    effect = CandidateEffect("charge_amp_highpass", [Column("charge_amp_highpass.time_constant_s", u)], (HIGHPASS,),
                             offset=u / tau, at={"time_constant_s": 1 / tau},
                             grid=tuple((1 / t, u / t) for t in (64.0, 16.0, 4.0, 1.0, 0.25)))
    lim, = detection_limits(problem, {effect.name: effect}, _calibration(problem, base))
    assert lim.at_most and "DC" in lim.note
    judge = dataclasses.replace(problem, rows=np.arange(4, n))  # without the force's DCs
    size = 1 / lim.value  # the change is linear in 1/tau on this grid: the limit is exact
    assert _score(problem, judge, missed + size * u, base, effect.columns, 1 + 4) == pytest.approx(NAME_MARGIN, rel=1e-6)


def test_a_change_the_baseline_makes_whole_has_no_limit():
    n = 50
    u = np.linspace(-1, 1, n)
    problem = _problem(np.zeros(n), np.ones(n))
    assert unexplained(problem, 3.0 * u, [Column("airgap", u)]) == 0.0
    effect = CandidateEffect("load_cell_compliance", [Column("load_cell_compliance.stiffness_n_per_m", u)],
                             PROBES["load_cell_compliance"])
    lim, = detection_limits(problem, {effect.name: effect}, _calibration(problem, [Column("airgap", u)]))
    assert not lim.in_range and lim.bound() == "none the catalogue's range reaches"
    assert json.dumps(lim.to_json(), allow_nan=False)


def test_of_a_familys_variants_the_lowest_limit_speaks_and_positions_have_none():
    rng = np.random.default_rng(2)
    n = 120
    problem = _problem(np.zeros(n), np.ones(n))
    u = rng.normal(size=n)
    three = CandidateEffect("channel_skew", [Column(f"channel_skew.{p.param}", u * (k + 1)) for k, p in
                                             enumerate(PROBES["channel_skew"])], PROBES["channel_skew"])
    alone = CandidateEffect("channel_skew@current_A", [Column("channel_skew@current_A.current_A", u)], (SKEW,))
    mode = CandidateEffect("frame_resonance@search", [Column(f"frame_resonance@search.{p.param}", u) for p in
                                                      PROBES["frame_resonance"]], PROBES["frame_resonance"],
                           offset=u, at={"frequency_hz": 900.0})
    limits = detection_limits(problem, {e.name: e for e in (three, alone, mode)}, _calibration(problem, []))
    by = {(lim.effect, lim.param): lim for lim in limits}
    # the variant alone is charged one parameter, the family three: the variant's limit is the lower
    assert by[("channel_skew", "current_A")].value == pytest.approx(
        math.sqrt((NAME_MARGIN + math.log(n)) / float(u @ u)), rel=1e-6)
    assert ("frame_resonance", "depth") in by
    assert ("frame_resonance", "frequency_hz") not in by and ("frame_resonance", "split") not in by


def test_on_a_grid_the_limit_is_where_the_simulated_changes_cross_the_threshold():
    """A change that grows as u^1.5 between grid values (chi2 as u^3, far from the quadratic one value
    would scale by): between two grid values the limit is their log-log interpolation, exact for a
    power law; beyond the grid's ends, quadratic from the nearest value."""
    n = 60
    sigma = np.ones(n)
    shape = np.sin(np.arange(n))
    columns = [Column("knob", np.random.default_rng(3).normal(size=n), prior=0.5)]
    grid = tuple((u, (u ** 1.5) * shape) for u in (1 / 64, 1 / 16, 1 / 4, 1.0))
    problem = _problem(np.zeros(n), sigma)
    q = _closed_form(shape, sigma, columns)
    assert size_on_grid(problem, grid, columns, q * (1 / 8) ** 3) == pytest.approx(1 / 8, rel=1e-6)
    assert size_on_grid(problem, grid, columns, q * (1 / 64) ** 3 / 4) == pytest.approx(1 / 128, rel=1e-6)
    assert size_on_grid(problem, grid, columns, 4 * q) == pytest.approx(2.0, rel=1e-6)


def test_a_time_constant_is_decided_up_to_its_limit_a_skew_from_it_and_a_drift_either_way():
    lim = _limit("charge_amp_highpass", "time_constant_s", 0.05, HIGHPASS)  # u = 1/tau
    assert lim.at_most and lim.value == pytest.approx(20.0) and lim.in_range
    assert lim.text() == "charge_amp_highpass time_constant_s <= 20 s"
    assert _limit("channel_skew", "current_A", 7.3e-7, SKEW).text() == "channel_skew current_A >= 7.3e-07 s"
    drift, = PROBES["magnet_thermal_drift"]  # a magnet may warm or cool
    assert _limit("magnet_thermal_drift", "kelvin_per_s", 0.08, drift).bound() == ">= 0.08 K/s either way"


def test_a_limit_beyond_the_catalogues_range_says_so():
    assert not _limit("channel_skew", "current_A", 2e-3, SKEW).in_range  # the catalogue's skews end at 1 ms
    assert not _limit("channel_skew", "current_A", math.inf, SKEW).in_range
    stiffness, = PROBES["load_cell_compliance"]  # the catalogue's stiffness starts at 1 N/m
    assert not _limit("load_cell_compliance", "stiffness_n_per_m", 10.0, stiffness).in_range  # 0.1 N/m
    assert _limit("load_cell_compliance", "stiffness_n_per_m", 1e-8, stiffness).in_range  # 1e8 N/m


def test_the_json_document_carries_every_limit_and_no_nan():
    d = Diagnosis(None, [], [], {}, {}, {}, math.nan, math.nan, {}, 0.0,
                  limits=[_limit("channel_skew", "current_A", math.inf, SKEW),
                          _limit("charge_amp_highpass", "time_constant_s", 0.05, HIGHPASS)])
    doc = json.loads(json.dumps(d.to_json(), allow_nan=False))
    assert doc["limits"]["channel_skew"]["current_A"] == {
        "value": None, "unit": "s", "at_most": False, "either_sign": False, "in_range": False, "note": "",
        "seen_at": {}}
    assert doc["limits"]["charge_amp_highpass"]["time_constant_s"]["value"] == pytest.approx(20.0)


def test_where_the_day_sees_an_effect_is_where_the_baseline_cannot_make_it():
    """Three operating points of 40 numbers each: the change is 3 on the first, 1 on the third, nothing on
    the second, and the baseline can make only a constant on the third: the day sees it at the first alone
    (all of what is left), not where it is largest before the baseline has its say."""
    n = 120
    record = np.repeat(np.arange(3), 40)
    layout = SimpleNamespace(size=n, channel=np.zeros(n, int), harmonic=np.ones(n, int), record=record)
    problem = _problem(np.zeros(n), np.ones(n), layout)
    change = np.where(record == 0, 3.0 * np.cos(np.arange(n)), 0.0) + np.where(record == 2, 5.0, 0.0)
    third = Column("third point's offset", (record == 2).astype(float))
    labels = ["ecore 40 Hz 1.27 A-pp", "ecore 80 Hz 1.27 A-pp", "voicecoil_ferrite 3000 Hz 1 A-pp"]
    assert seen_at(problem, change, [third], labels) == (("ecore 40 Hz 1.27 A-pp", 1.0),)
    both = np.where(record == 0, 3.0, 0.0) + np.where(record == 2, 1.0, 0.0)  # chi2 360 and 40: 90 %, 10 %
    assert seen_at(problem, both, [], labels) == (("ecore 40 Hz 1.27 A-pp", 0.9), ("voicecoil_ferrite 3000 Hz 1 A-pp", 0.1))
    effect = CandidateEffect("channel_skew@current_A", [Column("channel_skew@current_A.current_A", both)], (SKEW,))
    lim, = detection_limits(problem, {effect.name: effect}, _calibration(problem, []), labels)
    assert lim.seen_at == (("ecore 40 Hz 1.27 A-pp", 0.9), ("voicecoil_ferrite 3000 Hz 1 A-pp", 0.1))
