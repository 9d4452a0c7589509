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
from typing import Any, Callable, Sequence

import numpy as np

from .calibrate import Calibration
from .features import RecordFeatures
from .fit import Column, Problem
from .result import Loops
from .select import Selection
from .vector import record_harmonics

__all__ = ["cross_validate", "folds", "held_out"]


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


def held_out(problem: Problem, fold_rows: Sequence[tuple[np.ndarray, np.ndarray]], m: np.ndarray,
             columns: Sequence[Column], unit: np.ndarray | None = None,
             where: np.ndarray | None = None,
             per_fold: Callable[[np.ndarray], list[Column]] | None = None) -> tuple[float, np.ndarray]:
    """The held-out residual of the model ``m`` + ``columns`` (fitted on each fold's training rows): the
    rms over the held-out numbers of each one's error in units of its standard error (or of ``unit``,
    with the model-error floor: what forward selection judges by; only at ``where``, a mask, when
    given), and the held-out predictions (NaN elsewhere).  ``per_fold``: columns chosen on each fold's
    training rows alone (a mode searched again without the held-out points), added to ``columns``."""
    unit = problem.noise if unit is None else unit
    pred = np.full(problem.d.size, np.nan)
    num = den = 0.0
    for train, test in fold_rows:
        if where is not None:  # only the numbers a candidate moves
            test = test[where[test]]
            if not test.size:
                continue
        cols = list(columns) + (per_fold(train) if per_fold is not None else [])
        pred[test] = m[test] + problem.solve(m, cols, train).fitted[test]
        num += float(np.sum(((problem.d[test] - pred[test]) / unit[test]) ** 2))
        den += test.size
    return (math.sqrt(num / den) if den > 0 else math.nan), pred


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
