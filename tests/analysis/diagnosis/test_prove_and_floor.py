"""The proof's folds hold out every block's operating points (the voice coil's kHz points too), one fold
cannot decide the proof, and the model-error floor is set by the bulk of the residual, not by the few
numbers an effect moves."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from hystbench.analysis.diagnosis.fit import MODEL_ERROR_FLOOR, Problem, floor_scales
from hystbench.analysis.diagnosis.prove import FoldErrors, fold_errors, fold_gain, folds
from hystbench.analysis.diagnosis.vector import CHANNELS, Layout

FORCE = CHANNELS.index("force_N")


def _layout(n_records: int, per_record: int, se: float = 1.0, scale: float = 1.0) -> Layout:
    rec = np.repeat(np.arange(n_records), per_record)
    harm = np.tile(np.arange(1, per_record + 1), n_records)
    n = rec.size
    return Layout(rec, np.full(n, FORCE), harm, np.zeros(n, int), np.full(n, se), np.full(n, scale))


def test_every_block_is_held_out_by_frequency():
    rigs = [("voicecoil_ferrite", 40.0), ("ecore", 40.0), ("voicecoil_ferrite", 1000.0),
            ("voicecoil_ferrite", 3000.0), ("ecore", 80.0)]
    data = [SimpleNamespace(rig=r, frequency_hz=f, harmonics={}) for r, f in rigs]
    layout = _layout(len(data), 3)
    problem = Problem(np.zeros(layout.size), np.ones(layout.size), np.arange(layout.size), lambda r: [],
                      layout, np.ones(layout.size), np.zeros(0, int))
    held = {frozenset(layout.record[test]) for _, test in folds(problem, data)}
    assert held == {frozenset({0, 1}), frozenset({2}), frozenset({3}), frozenset({4})}
    for train, test in folds(problem, data):
        assert not set(train) & set(test)


def _errors(count, chi2) -> FoldErrors:
    return FoldErrors(np.asarray(count, float), np.asarray(chi2, float))


def test_a_fold_the_training_rows_cannot_pin_does_not_refuse_an_effect_every_other_fold_confirms():
    """Four folds 10x better predicted; the fifth, a resonance extrapolated (10^6 before), 2x worse.  The
    pooled ratio is the fifth fold's (sqrt((400 + 1e6) / (4 + 4e6)) = 0.50x); the proof says 10x."""
    before, after = _errors([1] * 5, [100] * 4 + [1e6]), _errors([1] * 5, [1] * 4 + [4e6])
    assert before.rms / after.rms < 0.51
    assert fold_gain(before, after) == 10.0


def test_one_fold_alone_cannot_carry_a_proof():
    """The mirror case: one fold 1000x better, four unchanged.  Pooled 447x; the median fold, 1x."""
    before, after = _errors([1] * 5, [1] * 4 + [1e6]), _errors([1] * 5, [1] * 5)
    assert before.rms / after.rms > 400
    assert fold_gain(before, after) == 1.0


def test_each_fold_weighs_by_its_numbers_and_a_fold_with_none_is_not_a_vote():
    """A fold of ten numbers unchanged outweighs three of one number each 9x better (ten of thirteen
    numbers: the median is in the big fold); a fold with no numbers where the effect acts is no vote."""
    before = _errors([10, 1, 1, 1, 0], [10, 81, 81, 81, 0])
    after = _errors([10, 1, 1, 1, 0], [10, 1, 1, 1, 0])
    assert fold_gain(before, after) == 1.0
    assert fold_gain(_errors([3, 0], [27, 0]), _errors([3, 0], [3, 0])) == 3.0
    assert math.isnan(fold_gain(_errors([0, 0], [0, 0]), _errors([0, 0], [0, 0])))


def test_of_two_folds_the_worse_decides_and_an_exact_fold_is_no_change():
    """The lower median: two folds 10x and 1x better give 1x (both must hold); a fold both sides predict
    exactly is a ratio of 1, not 0/0; sides holding out different numbers are an error."""
    assert fold_gain(_errors([2, 2], [200, 2]), _errors([2, 2], [2, 2])) == 1.0
    assert fold_gain(_errors([1, 1, 1], [0, 4, 4]), _errors([1, 1, 1], [0, 1, 1])) == 2.0
    with pytest.raises(ValueError, match="different numbers"):
        fold_gain(_errors([1, 2], [1, 1]), _errors([2, 1], [1, 1]))


def test_fold_errors_sum_each_folds_held_out_numbers_only_where_asked():
    """Per fold, the count and squared error of the numbers held out (and in ``where``), computed here
    independently from the data: a model of zeros and no columns predicts 0 everywhere."""
    rigs = [("ecore", 40.0), ("ecore", 80.0), ("ecore", 160.0)]
    data = [SimpleNamespace(rig=r, frequency_hz=f, harmonics={}) for r, f in rigs]
    layout = _layout(len(data), 4)
    d = np.arange(1.0, layout.size + 1)
    problem = Problem(d, np.ones(layout.size), np.arange(layout.size), lambda r: [], layout,
                      np.ones(layout.size), np.zeros(0, int))
    where = layout.harmonic <= 2
    errors, pred = fold_errors(problem, folds(problem, data), np.zeros(layout.size), [], where=where)
    expect = [float(np.sum(d[(layout.record == r) & where] ** 2)) for r in range(3)]
    assert errors.count.tolist() == [2, 2, 2] and errors.chi2.tolist() == expect
    assert np.all(np.isnan(pred[~where])) and np.array_equal(pred[where], np.zeros(6))
    assert errors.rms == math.sqrt(sum(expect) / 6)


def test_a_few_large_residuals_do_not_raise_the_floor():
    rng = np.random.default_rng(4)
    n = 400
    layout = _layout(1, n, se=1.0, scale=1.0 / MODEL_ERROR_FLOOR["force vs current"])  # the floor's unit: 1 se
    data = [SimpleNamespace(rig="voicecoil_ferrite")]
    ok = np.ones(n, bool)
    noise = rng.normal(size=n)
    local = noise.copy()
    local[:12] += 60.0  # a frame mode near a few points: 3 % of the numbers
    # the mean of the squares would ask for a floor ten times the noise (1 + 12 * 3600 / 400 = 109);
    # the median leaves it below the noise, where nothing hides
    assert floor_scales(local, layout, data, ok)[0] < 1.0
    broad = noise * 3.0  # a baseline that misses everywhere by three times its noise
    assert 2.5 < floor_scales(broad, layout, data, ok)[0] < 3.5  # floor^2 + se^2 = 9 se^2: about 2.8


def test_named_effects_that_leave_the_total_worse_predicted_are_a_finding():
    """The independent bench's relaxation day: a frame mode proven at 1.55x in its signature while the
    held-out residual in total went 24.5 -> 133 noise floors (docs/diagnosis.md): said, not hidden."""
    from hystbench.analysis.diagnosis import worse_in_total

    (said,) = worse_in_total(["frame_resonance"], 24.5, 133.0)
    assert "frame_resonance" in said and "24.5 -> 133" in said
    assert worse_in_total(["integrator_leak"], 141.0, 22.8) == []  # better in total: nothing to say
    assert worse_in_total([], 20.0, 20.0) == []
