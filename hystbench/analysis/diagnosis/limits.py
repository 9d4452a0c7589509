"""What a bench day can decide: the size of each candidate effect at which the day would name it.

A "none" means one of two things: the effect is not there, or it is there but smaller than what this
day's data can tell from a baseline allowed to be wrong.  A bench engineer who reads "none" must know
which; so must one who reads a miss in the benchmark (was it below the day's reach, or lost to a
look-alike or to the held-out proof?).

For each candidate's parameter, the others off: its change of the bench day's numbers per unit (its
column, measured from off), and the score an effect of size a that is this change on top of today's fit
would expect, as :func:`.select.forward_selection` scores it: what of a times the change the calibrated
baseline's columns (knobs and discrepancy, with their priors; none is bounded) cannot make, in the day's
sigmas, minus the effect's charge (ln n per parameter, and the DCs a DC-blind effect frees, against what
the baseline misses there today).  That is a^2 q, so the limit is a = sqrt(threshold / q).  A time
constant is followed on its grid of replays instead (a high-pass's change is far from linear in 1/tau).

It is the expected limit: the day's own residual moves a real score either way (by its projection on
the change), the runner-up must still be beaten and the held-out proof passed, and what the replay does
not simulate is not in it (a high-pass loses the force's DC over the whole day, from a reset the
recordings do not give; the replay follows MEMORY_CAP_S of it).  ``python -m benchmarks limits`` measures
how well it predicts whole diagnoses.
"""

from __future__ import annotations

import math
import dataclasses
from typing import Mapping, Sequence

import numpy as np

from ...config.effects import CATALOGUE
from .calibrate import Calibration
from .columns import Probe
from .fit import Column, Problem, solve
from .forward import MEMORY_CAP_S
from .result import Limit
from .select import DC_BLIND, NAME_MARGIN, CandidateEffect, family, judged_as

__all__ = ["detection_limits", "unexplained", "seen_at", "size_on_grid", "NOT_A_SIZE", "ABSORBED"]

#: Parameters beside an effect's size that place or shape it (a searched mode's frequency, two modes' split,
#: a relaxation's time constant): no limit of their own.
NOT_A_SIZE = {("frame_resonance", "split"), ("frame_resonance", "frequency_hz"), ("magnetic_relaxation", "time_constant_s")}
#: Less than this share of a change left unexplained is a change the baseline makes whole (rounding).
ABSORBED = 1e-12
#: Where the day sees an effect: its largest operating points, each with at least this share.
SEEN_AT, MIN_SHARE = 2, 0.1


def detection_limits(problem: Problem, effects: Mapping[str, CandidateEffect], calibration: Calibration,
                     labels: Sequence[str] | None = None) -> list[Limit]:
    """Each candidate parameter's limit against the calibrated baseline (module docstring); of a
    family's variants (a skew of one channel, of all three) the lowest speaks for it, as its best variant's
    score does.  Mains pick-up is scored on lines whose size is measured directly: no limit here.
    ``labels``: each record's operating point ("voicecoil_ferrite 3000 Hz 1 A-pp"), for where the day sees
    each effect (:attr:`Limit.seen_at`: the points to play more of to lower its limit)."""
    log_n = math.log(problem.rows.size)
    missed = (problem.d - calibration.m0 - calibration.residual) / problem.sigma
    best: dict[tuple[str, str], tuple[float, Probe, str, np.ndarray | None]] = {}
    for key, eff in effects.items():
        if eff.line_hz is not None:
            continue
        judge, freed = judged_as(problem, key)
        # its DCs are free parameters: charged, and credited with what the baseline misses there today
        credit = float(np.sum(missed[np.setdiff1d(problem.rows, judge.rows)] ** 2))
        threshold = NAME_MARGIN + (len(eff.columns) + freed) * log_n - credit
        note = (f"its DC replayed over {MEMORY_CAP_S:g} s: the {DC_BLIND[family(key)]} DC it loses over a whole "
                "day may decide longer ones") if freed else ""
        for i, (probe, column) in enumerate(zip(eff.probes, eff.columns)):
            if (family(key), probe.param) in NOT_A_SIZE:
                continue
            if eff.grid:  # its only parameter, on a grid
                size = size_on_grid(problem, eff.grid, calibration.columns, threshold)
                left = _fit(problem, _nearest(eff.grid, size), calibration.columns)[1]
            elif eff.offset is None or i > 0:  # measured from off, or a size beside a searched position
                q, left = _fit(problem, column.values, calibration.columns)
                size = _size(q, threshold)
            else:  # a gridded position beside a size of its own, not listed in NOT_A_SIZE: no limit
                continue
            k = (family(key), probe.param)
            if k not in best or size < best[k][0]:
                best[k] = (size, probe, note, left)
    return [dataclasses.replace(_limit(fam, param, size, probe, note), seen_at=_shares(problem, left, labels))
            for (fam, param), (size, probe, note, left) in best.items()]


def unexplained(problem: Problem, change: np.ndarray, columns: list[Column]) -> float:
    """What of ``change`` the ``columns`` cannot make, with their priors: chi-square in the day's sigmas
    (NaN when the change is not finite on the rows that count; 0 when the columns make it whole)."""
    return _fit(problem, change, columns)[0]


def seen_at(problem: Problem, change: np.ndarray, columns: list[Column], labels: Sequence[str],
            top: int = SEEN_AT) -> tuple[tuple[str, float], ...]:
    """Where the day sees ``change``: the share of what ``columns`` cannot make of it, by the operating
    point (``labels``, one per record) of the rows it is on, the ``top`` largest (at least MIN_SHARE)."""
    return _shares(problem, _fit(problem, change, columns)[1], labels, top)


def _fit(problem: Problem, change: np.ndarray, columns: list[Column]) -> tuple[float, np.ndarray | None]:
    """:func:`unexplained`, and what is left of the change on each row that counts, in its sigmas."""
    rows = problem.rows
    if not np.all(np.isfinite(change[rows])):
        return math.nan, None
    sol = solve(change, problem.sigma, columns, rows)
    left = sol.chi2 + sol.chi2_prior
    whole = float(np.sum((change[rows] / problem.sigma[rows]) ** 2))
    return (left if left > ABSORBED * whole else 0.0), (change - sol.fitted)[rows] / problem.sigma[rows]


def _shares(problem: Problem, left: np.ndarray | None, labels: Sequence[str] | None,
            top: int = SEEN_AT) -> tuple[tuple[str, float], ...]:
    if left is None or not labels:
        return ()
    record = np.concatenate([problem.layout.record, problem.line_records])[problem.rows]
    by: dict[str, float] = {}
    for label, x in zip(labels, np.bincount(record, weights=left ** 2, minlength=len(labels))):
        by[label] = by.get(label, 0.0) + float(x)
    total = sum(by.values())
    if not total > 0:
        return ()
    shares = sorted(((k, v / total) for k, v in by.items()), key=lambda kv: -kv[1])
    return tuple((k, round(v, 3)) for k, v in shares[:top] if v >= MIN_SHARE)


def _size(q: float, threshold: float) -> float:
    """The size a at which a^2 ``q`` is worth ``threshold`` (the columns are unbounded: quadratic); inf
    when nothing of the change is left or it is not finite, 0 when today's credit already passes it."""
    if threshold <= 0:
        return 0.0
    return math.sqrt(threshold / q) if q > 0 else math.inf


def size_on_grid(problem: Problem, grid: tuple[tuple[float, np.ndarray], ...], columns: list[Column],
                 threshold: float) -> float:
    """The smallest u whose change, simulated on the grid, reaches ``threshold``: interpolated in log-log
    between the two grid values that bracket it, beyond the grid quadratic from its nearest end (as a
    change small against the noise is); inf when the columns make every change whole."""
    if threshold <= 0:
        return 0.0
    u = np.array([g[0] for g in grid])
    s = np.array([unexplained(problem, change, columns) for _, change in grid])
    s = np.where(np.isfinite(s), s, 0.0)
    if not np.any(s > 0):
        return math.inf
    above = np.flatnonzero(s >= threshold)
    if not above.size:
        last = int(np.flatnonzero(s > 0)[-1])
        return float(u[last] * math.sqrt(threshold / s[last]))
    k = int(above[0])
    if k == 0 or s[k - 1] <= 0:
        return float(u[k] * math.sqrt(threshold / s[k]))
    t = (math.log(threshold) - math.log(s[k - 1])) / (math.log(s[k]) - math.log(s[k - 1]))
    return float(math.exp(math.log(u[k - 1]) + t * (math.log(u[k]) - math.log(u[k - 1]))))


def _nearest(grid: tuple[tuple[float, np.ndarray], ...], size: float) -> np.ndarray:
    """The grid's change nearest ``size`` in log (the largest u's when there is no finite size)."""
    if not 0 < size < math.inf:
        return grid[-1][1]
    return min(grid, key=lambda g: abs(math.log(g[0] / size)))[1]


def _limit(effect: str, param: str, size: float, probe: Probe, note: str = "") -> Limit:
    """The size u in the catalogue's units, and whether the catalogue's range reaches it."""
    at_most = probe.inverse  # 1/u: a larger effect is a smaller value
    if math.isfinite(size):
        value = probe.value(size) if size > 0 else (math.inf if at_most else 0.0)
    else:
        value = 0.0 if at_most else math.inf
    key = CATALOGUE[effect].params.get(param)
    unit = key.unit if key is not None else ("x the catalogue's" if probe.is_switch else "")
    if at_most:  # decided from 0 up to value: the catalogue's lower end must be below it
        in_range = value > 0 and (key is None or ((key.ge is None or value >= key.ge)
                                                  and (key.gt is None or value > key.gt)))
    else:  # decided from value up: the catalogue's upper end must be above it
        in_range = math.isfinite(value) and (key is None or ((key.le is None or value <= key.le)
                                                             and (key.lt is None or value < key.lt)))
    return Limit(effect, param, float(value), unit, at_most, bool(in_range), note, either_sign=probe.lower < 0)
