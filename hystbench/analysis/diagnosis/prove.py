"""Stage 5 of a diagnosis: prove the fit improves, on recordings the fit never saw.

Cross-validation over operating points: each fold holds out one excitation frequency on every rig
that played it (the voice coil's kHz points included); the calibration, its discrepancy and the named
effects are fitted on the rest and predict the held-out harmonics and lines.  The residual is in units of
their standard errors (the noise floor of each period average), before (the calibrated baseline) and
after (with the named effects).  The held-out recording the baseline missed most is kept as one period
of measured and predicted signals for the report's loops.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Callable, Sequence

import numpy as np

from .calibrate import Calibration
from .features import RecordFeatures
from .fit import Column, Problem
from .result import Loops
from .vector import record_harmonics

if TYPE_CHECKING:  # select judges its candidates by this module's folds
    from .select import Selection

__all__ = ["FoldErrors", "cross_validate", "fold_errors", "fold_gain", "folds", "held_out", "total_gain"]


def folds(problem: Problem, data: Sequence[RecordFeatures]) -> list[tuple[np.ndarray, np.ndarray]]:
    """(training rows, held-out rows) per fold: one excitation frequency held out on every rig that
    played it (the voice coil's kHz points too: a frame mode shows only there), every channel's
    harmonics and the non-harmonic lines of those recordings judged.  A bench day with a single
    frequency holds out one recording at a time."""
    layout, rows = problem.layout, problem.rows
    group = {r: round(f.frequency_hz) for r, f in enumerate(data)}
    if len(set(group.values())) < 2:
        group = {r: r for r in group}
    rec_of = np.concatenate([layout.record, problem.line_records])[rows]
    out = []
    for g in sorted(set(group.values())):
        held = np.isin(rec_of, [r for r, gg in group.items() if gg == g])
        test, train = rows[held], rows[~held]
        if test.size and train.size:
            out.append((train, test))
    return out


@dataclass(frozen=True)
class FoldErrors:
    """Each fold's held-out numbers: how many, and the sum of their squared errors in units."""

    count: np.ndarray
    chi2: np.ndarray

    @property
    def rms(self) -> float:
        n = float(self.count.sum())
        return math.sqrt(float(self.chi2.sum()) / n) if n > 0 else math.nan


def fold_errors(problem: Problem, fold_rows: Sequence[tuple[np.ndarray, np.ndarray]], m: np.ndarray,
                columns: Sequence[Column], unit: np.ndarray | None = None,
                where: np.ndarray | None = None,
                per_fold: Callable[[np.ndarray], list[Column]] | None = None) -> tuple[FoldErrors, np.ndarray]:
    """The held-out errors of the model ``m`` + ``columns`` (fitted on each fold's training rows), fold by
    fold, in units of each number's standard error (or of ``unit``, with the model-error floor: what
    forward selection judges by; only at ``where``, a mask, when given: a fold with none there counts
    0), and the held-out predictions (NaN elsewhere).  ``per_fold``: columns chosen on each fold's
    training rows alone (a mode searched again without the held-out points), added to ``columns``."""
    unit = problem.noise if unit is None else unit
    pred = np.full(problem.d.size, np.nan)
    count, chi2 = np.zeros(len(fold_rows)), np.zeros(len(fold_rows))
    for k, (train, test) in enumerate(fold_rows):
        if where is not None:  # only the numbers a candidate moves
            test = test[where[test]]
            if not test.size:
                continue
        cols = list(columns) + (per_fold(train) if per_fold is not None else [])
        pred[test] = m[test] + problem.solve(m, cols, train).fitted[test]
        count[k], chi2[k] = test.size, float(np.sum(((problem.d[test] - pred[test]) / unit[test]) ** 2))
    return FoldErrors(count, chi2), pred


def held_out(problem: Problem, fold_rows: Sequence[tuple[np.ndarray, np.ndarray]], m: np.ndarray,
             columns: Sequence[Column], unit: np.ndarray | None = None,
             where: np.ndarray | None = None,
             per_fold: Callable[[np.ndarray], list[Column]] | None = None) -> tuple[float, np.ndarray]:
    """The rms over every held-out number of :func:`fold_errors`, and the held-out predictions."""
    errors, pred = fold_errors(problem, fold_rows, m, columns, unit, where, per_fold)
    return errors.rms, pred


def fold_gain(before: FoldErrors, after: FoldErrors) -> float:
    """How much better ``after`` predicts the held-out operating points than ``before``: the median over
    folds of each fold's rms ratio, each fold weighted by its count of numbers (the lower median: of two
    folds, the worse; a fold with no numbers is no vote, and NaN with none at all).

    Not the ratio of the pooled sums, which one fold can decide: a fold the training rows cannot pin (the
    load cell's resonance extrapolated when the voice coil's top kHz point is held out) carries more
    squared error than all the others together, and a candidate that moves it a little passed or failed
    on that fold alone, whatever it did at every other frequency (docs/diagnosis.md, "A proof that one
    fold cannot decide").  A fold that holds half the numbers or more still decides."""
    if not np.array_equal(before.count, after.count):
        raise ValueError(f"fold_gain: the two sides hold out different numbers ({before.count} and {after.count})")
    seen = before.count > 0
    if not np.any(seen):
        return math.nan
    b, a = before.chi2[seen], after.chi2[seen]
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where((a == 0) & (b == 0), 1.0, np.sqrt(b / a))  # both exact: no change
    order = np.argsort(ratio)
    share = np.cumsum(before.count[seen][order]) / before.count[seen].sum()
    return float(ratio[order][np.searchsorted(share, 0.5)])


def total_gain(before: FoldErrors, after: FoldErrors) -> float:
    """How much better ``after`` predicts every held-out number together (the ratio of the pooled rms,
    as the tables' signature improvement): a named effect may not make it more than 1/MIN_TOTAL_GAIN
    worse, whatever its median fold.  NaN when no number was held out; inf when ``after`` is exact."""
    b, a = before.rms, after.rms
    if math.isnan(a) or math.isnan(b):
        return math.nan
    return 1.0 if a == b == 0 else (b / a if a > 0 else math.inf)


def cross_validate(problem: Problem, data: Sequence[RecordFeatures], before: Calibration,
                   selection: Selection) -> dict[str, Any]:
    """Stage 5 (module docstring): the held-out residual before and after, and the loops."""
    layout, d, n_h = problem.layout, problem.d, problem.layout.size
    fold_rows = folds(problem, data)
    before_res, pred_before = held_out(problem, fold_rows, before.m0, before.columns)
    if selection.named:
        after_res, pred_after = held_out(problem, fold_rows, selection.model,
                                         selection.calibration.columns + selection.columns)
    else:
        after_res, pred_after = before_res, pred_before
    loops = None
    tested = np.flatnonzero(np.isfinite(pred_before[:n_h]))
    if tested.size:
        err = {}
        for i in tested:
            r = int(layout.record[i])
            err[r] = err.get(r, 0.0) + ((d[i] - pred_before[i]) / layout.se[i]) ** 2
        worst = max(err, key=err.get)
        phase = np.linspace(0.0, 1.0, 256, endpoint=False)
        f = data[worst]
        meas = record_harmonics(np.where(np.isfinite(pred_before), d, np.nan), layout, worst)
        bef = record_harmonics(pred_before, layout, worst)
        aft = record_harmonics(pred_after, layout, worst)
        loops = Loops(f.name, f.rig, f.frequency_hz, f.current_pp_a, phase,
                      {c: period(np.nan_to_num(h), phase) for c, h in meas.items()},
                      {c: period(np.nan_to_num(h), phase) for c, h in bef.items()},
                      {c: period(np.nan_to_num(h), phase) for c, h in aft.items()})
        cur = f.harmonics.get("current_A")  # measured: its fundamental is the replay's input, not a row
        if cur is not None:
            for part in (loops.measured, loops.before, loops.after):
                part["current_A"] = period(np.nan_to_num(cur), phase)
    return {"before": before_res, "after": after_res, "loops": loops}


def period(h: np.ndarray, phase: np.ndarray) -> np.ndarray:
    """One period from harmonics ``h`` (features' convention: X_0 + sum Re(X_k e^{ikwt})) at ``phase`` (cycles)."""
    k = np.arange(h.size)
    return (h[None, :] * np.exp(2j * np.pi * np.outer(phase, k))).real.sum(axis=1)
