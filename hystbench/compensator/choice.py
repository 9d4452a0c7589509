"""The best model is the description the sweep's held-out recordings choose, among all of them.

Every description -- the paper's Eq. 1 (``nonhysteretic``) and Eq. 6 (``paper``) and the iron
descriptions of :mod:`.identify` (``rayleigh_loop``, ``describing_function``, ``preisach``) -- is
fitted on the sweep with operating points held out (whole inner frequencies, whole inner amplitudes:
:func:`.identify.held_out_folds`) and judged on them by the figure users judge a model by, the
accuracy 100 % (1 - max|dF| / force range) of each held-out recording.

A description's *shortfall* on a recording is how far its accuracy falls below the best any
description reaches there.  A user asks for the best model on every recording, not on average, so:

1. a description whose shortfall stays within the noise of the recording's period average (one
   standard deviation of its accuracy) on every held-out recording is as good as the best; if any
   is, the simplest of them is chosen (:data:`SIMPLICITY`): more parameters must earn their place;
2. else the description whose largest shortfall is smallest.

The winner is refitted on the whole sweep; :func:`choose_best`'s report says which, why, and every
description's held-out accuracies.
"""

from __future__ import annotations

import math
from typing import Any, Callable, Sequence

from ..physics.instrument import InstrumentModel
from .calibration import SweepCalibration, fit_delayed_law
from .data import PeriodData
from .errors import CompensatorError
from .hysteresis_eddy import IronScaling
from .identify import CANDIDATES, IronData, held_out_folds, iron_data
from .force_model import ForceModel, NonHysteretic, force_error, paper_model

__all__ = ["SIMPLICITY", "choose_best", "fit_descriptions", "accuracy_noise_pct"]

#: Every description, simplest first (parameters: Eq. 1's law; Eq. 6 adds a delay per frequency; the
#: Rayleigh loop six linear terms; the describing function eight; the Preisach iron its distributions).
SIMPLICITY = ("nonhysteretic", "paper", "rayleigh_loop", "describing_function", "preisach")

Fit = Callable[[Sequence[PeriodData], IronData], ForceModel]


def _fitters(cal: SweepCalibration, scaling: IronScaling, instrument: InstrumentModel, magnet: bool) -> dict[str, Fit]:
    def nonhysteretic(points: Sequence[PeriodData], _: IronData) -> ForceModel:
        return NonHysteretic(fit_delayed_law(points, instrument, magnet)[0], kind="best")

    def paper(points: Sequence[PeriodData], _: IronData) -> ForceModel:
        return paper_model(points, fit_delayed_law(points, instrument, magnet)[0], kind="best")

    fits: dict[str, Fit] = {"nonhysteretic": nonhysteretic, "paper": paper}
    for name, fit in CANDIDATES.items():
        fits[name] = lambda _points, data, fit=fit: fit(data, cal, scaling)
    return {name: fits[name] for name in SIMPLICITY}


def fit_descriptions(points: Sequence[PeriodData], cal: SweepCalibration, scaling: IronScaling,
                     instrument: InstrumentModel, magnet: bool) -> dict[str, ForceModel | CompensatorError]:
    """Every description fitted on the whole sweep (or the error that stopped its fit): what the
    choice chose among, for a benchmark to judge each on recordings the sweep does not hold."""
    data = iron_data(points, cal)
    out: dict[str, ForceModel | CompensatorError] = {}
    for name, fit in _fitters(cal, scaling, instrument, magnet).items():
        try:
            out[name] = fit(points, data)
        except CompensatorError as err:
            out[name] = err
    return out


def accuracy_noise_pct(point: PeriodData) -> float:
    """One standard deviation of a recording's accuracy from the noise of its period average, %."""
    if not (point.periods > 0 and math.isfinite(point.force_noise_rms_n)):
        return 0.0
    return 100.0 * point.force_noise_rms_n / math.sqrt(point.periods) / max(point.force_range_n, 1e-12)


def choose_best(points: Sequence[PeriodData], cal: SweepCalibration, scaling: IronScaling,
                instrument: InstrumentModel, magnet: bool,
                tick: Callable[[], None] | None = None) -> tuple[ForceModel, dict[str, Any]]:
    """The best model of the sweep (module docstring) and the report of the choice."""
    fits = _fitters(cal, scaling, instrument, magnet)
    data = iron_data(points, cal)
    folds = held_out_folds(points)
    if not folds:  # nothing to judge on: every figure of the choice was NaN, in a file its readers refuse
        raise CompensatorError(f"choosing a description holds an operating point out and fits on at least three "
                               f"others; these {len(points)} recordings ({', '.join(p.name for p in points)}) leave "
                               "none to hold out: record more frequencies or amplitudes")
    held: dict[str, dict[str, float]] = {}
    failed: dict[str, str] = {}
    for name, fit in fits.items():
        acc: dict[str, float] = {}
        try:
            for _, out in folds:
                keep = [k for k in range(len(points)) if k not in out]
                model = fit([points[k] for k in keep], data.subset(keep))
                for k in out:
                    acc[points[k].name] = force_error(model, points[k], instrument)["accuracy_pct"]
                if tick is not None:
                    tick()
        except CompensatorError as err:
            failed[name] = str(err)
            continue
        held[name] = acc
    if not held:
        raise CompensatorError("no description of the force fits this sweep: "
                               + "; ".join(f"{k}: {v}" for k, v in failed.items()))
    noise = {p.name: accuracy_noise_pct(p) for p in points}
    recordings = list(next(iter(held.values())))
    best_at = {n: max(acc[n] for acc in held.values()) for n in recordings}
    shortfall = {d: {n: best_at[n] - acc[n] for n in recordings} for d, acc in held.items()}
    largest = {d: max(s.values(), default=0.0) for d, s in shortfall.items()}
    as_good = [d for d in held if all(shortfall[d][n] <= noise[n] for n in recordings)]
    if as_good:
        chosen = as_good[0]  # held keeps SIMPLICITY's order
        why = ("within the noise of the best on every held-out recording" +
               (f", and the simplest of those that are ({', '.join(as_good)})" if len(as_good) > 1 else ""))
    else:
        chosen = min(held, key=lambda d: largest[d])
        worst = max(shortfall[chosen], key=shortfall[chosen].get)
        why = (f"no description is within the noise of the best everywhere; its largest shortfall, "
               f"{largest[chosen]:.3f} points on {worst}, is the smallest")
    worst_acc = {d: min(acc.values(), default=math.nan) for d, acc in held.items()}
    model = fits[chosen](points, data)
    report = {
        "chosen": chosen,
        "why": f"{chosen}: {why} (held out: {', '.join(n for n, _ in folds)})",
        "held_out_accuracy_pct": held, "worst_held_out_accuracy_pct": worst_acc,
        "largest_shortfall_pts": largest, "accuracy_noise_pct": {n: noise[n] for n in recordings},
        "failed": failed, "simplicity": list(SIMPLICITY),
    }
    return model, report
