"""The frame mode search (analysis/diagnosis/search.py) finds a mode of a bench not ours from the force
harmonics alone: its frequency between two measured points, its damping, and the side its gain steps;
and its proof searches again in each fold, so a mode placed on one played frequency predicts nothing."""

from __future__ import annotations

import dataclasses

import numpy as np
from scipy import signal

from hystbench.analysis.diagnosis.fit import Problem
from hystbench.analysis.diagnosis.prove import held_out
from hystbench.analysis.diagnosis.search import frame_mode_search
from hystbench.analysis.diagnosis.select import _mode_research
from hystbench.analysis.diagnosis.vector import CHANNELS, Layout

FORCE = CHANNELS.index("force_N")


def _mode(f_hz: np.ndarray, f_mode: float, zeta: float, depth: float, f_zero: float) -> np.ndarray:
    """A two-mass frame mode's response, from its poles and zeros (scipy.signal.freqs, not the search's
    closed form): unity DC gain."""
    wp, wz = 2 * np.pi * f_mode, 2 * np.pi * f_zero
    b = [1 / wz**2, 2 * zeta * (1 + depth) / wz, 1.0]
    a = [1 / wp**2, 2 * zeta / wp, 1.0]
    return signal.freqs(b, a, worN=2 * np.pi * f_hz)[1]


def test_a_mode_between_the_voice_coils_points_is_found():
    freqs = np.array([40.0, 80.0, 160.0, 320.0, 640.0, 1000.0, 1500.0, 2000.0, 3000.0])  # the voice coil's day
    K = 3
    rec = np.repeat(np.arange(freqs.size), 2 * K)
    harm = np.tile(np.repeat(np.arange(1, K + 1), 2), freqs.size)
    part = np.tile([0, 1], freqs.size * K)
    F = 2.0 / harm.astype(float) * np.exp(-0.3j * harm)  # the model's force harmonics (any)
    truth = F * _mode(harm * freqs[rec], 1175.0, 0.015, 0.3, 1175.0 * 1.01)
    vec = lambda z: np.where(part == 0, z.real, z.imag)  # noqa: E731
    se = np.full(rec.size, 1e-4)
    layout = Layout(rec, np.full(rec.size, FORCE), harm, part, se, np.full(rec.size, 2.0))
    rng = np.random.default_rng(2)
    d = vec(truth) + rng.normal(scale=1e-4, size=rec.size)
    problem = Problem(d, se, np.arange(rec.size), lambda r: [], layout, se, np.zeros(0, int))
    found = frame_mode_search(problem, vec(F), [], freqs)
    assert abs(found["frequency_hz"] / 1175.0 - 1) < 0.03, found
    assert found["split"] > 0, found  # the anti-resonance above the resonance
    assert found["depth"] > 0, found


def _e_core_day(seed: int, mode: tuple[float, float, float] | None, bump: complex = 0j):
    """An E-core day's force harmonics (40-480 Hz, k = 1..7) and a model without the frame: the data
    carry a true mode (frequency, damping, depth) or none, plus ``bump``, a misfit of the 480 Hz
    point's fundamental alone (an iron the model does not describe, not a mode)."""
    freqs = np.array([40.0, 80.0, 160.0, 320.0, 480.0])
    K = 7
    rec = np.repeat(np.arange(freqs.size), 2 * K)
    harm = np.tile(np.repeat(np.arange(1, K + 1), 2), freqs.size)
    part = np.tile([0, 1], freqs.size * K)
    F = 2.0 / harm.astype(float) ** 2 * np.exp(-0.3j * harm)
    truth = F * (_mode(harm * freqs[rec], mode[0], mode[1], mode[2], mode[0] * 1.01) if mode else 1.0)
    truth = truth + np.where((freqs[rec] == 480.0) & (harm == 1), bump, 0.0)
    vec = lambda z: np.where(part == 0, z.real, z.imag)  # noqa: E731
    se = np.full(rec.size, 1e-4)
    layout = Layout(rec, np.full(rec.size, FORCE), harm, part, se, np.full(rec.size, 2.0))
    d = vec(truth) + np.random.default_rng(seed).normal(scale=1e-4, size=rec.size)
    problem = Problem(d, se, np.arange(rec.size), lambda r: [], layout, se, np.zeros(0, int))
    return problem, vec(F), freqs


def _folds(problem: Problem, freqs: np.ndarray):
    """One frequency held out at a time (prove.folds' rule, on harmonic rows alone)."""
    rec = problem.layout.record
    return [(np.flatnonzero(rec != r), np.flatnonzero(rec == r)) for r in range(freqs.size)]


def test_a_mode_searched_again_in_each_fold_never_sees_the_held_out_points():
    problem, m, freqs = _e_core_day(3, (300.0, 0.02, 0.4))
    search_again = _mode_research(problem, freqs, None)
    for train, test in _folds(problem, freqs):
        moved = dataclasses.replace(problem, d=problem.d.copy())
        moved.d[test] += np.random.default_rng(7).normal(scale=0.05, size=test.size)  # anything at all there
        same = _mode_research(moved, freqs, None)(train, m, [])
        for a, b in zip(search_again(train, m, []), same):
            np.testing.assert_array_equal(a.values, b.values)


def test_a_true_mode_searched_again_predicts_the_held_out_frequencies():
    """A mode at 300 Hz shows in the harmonics of every point (k f up to 3.4 kHz): found again without
    any one frequency, it predicts that one far better than the model without it."""
    problem, m, freqs = _e_core_day(4, (300.0, 0.02, 0.4))
    folds = _folds(problem, freqs)
    before, _ = held_out(problem, folds, m, [])
    after, _ = held_out(problem, folds, m, [], per_fold=lambda train: _mode_research(problem, freqs, None)(train, m, []))
    assert before / after > 5.0, (before, after)


def test_a_misfit_of_one_played_frequency_is_placed_but_not_predicted_by_a_mode():
    """A misfit of the 480 Hz point alone: the search puts a sharp mode on it when it sees that point;
    searched again without it, as the proof does, the mode predicts nothing there."""
    problem, m, freqs = _e_core_day(5, None, bump=0.02 - 0.01j)
    placed = frame_mode_search(problem, m, [], freqs)
    assert abs(placed["frequency_hz"] / 480.0 - 1) < 0.05, placed  # the search alone is fooled
    folds = _folds(problem, freqs)
    before, _ = held_out(problem, folds, m, [])
    again, _ = held_out(problem, folds, m, [], per_fold=lambda train: _mode_research(problem, freqs, None)(train, m, []))
    assert before / again < 1.5, (before, again)
