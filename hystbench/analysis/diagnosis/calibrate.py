"""Stage 1 of a diagnosis: calibrate the baseline simulation against the bench day.

What a bench engineer would calibrate, each against its prior from the preset (the knobs of
:mod:`.columns`: the load cell, the airgap, the magnet, the voice coil's Bl, the eddy currents'
conductivities, the frame's depth, the flux and force sensitivities), jointly with the explicit
discrepancy of :mod:`.discrepancy` (the iron's and the force law's: what no physical parameter of the
preset reaches goes there, not into a parameter pushed far from its prior).  A parameter the data push
beyond FAR_FROM_PRIOR prior widths is a finding of its own."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from .columns import GAINS, KNOBS, Knob, Simulator
from .discrepancy import discrepancy_columns
from .features import RecordFeatures
from .fit import Column, Problem, Solution
from .vector import CHANNELS, Layout

__all__ = ["Calibration", "calibrate", "recalibrated", "FAR_FROM_PRIOR"]

#: A calibration parameter this many prior widths from its preset is reported as a finding.
FAR_FROM_PRIOR = 3.0
#: Re-linearise the calibration when a knob moved more than this (log factor).
RELINEARISE = 0.05
#: At most this many re-linearisations of the calibration.
GAUSS_NEWTON_STEPS = 4


@dataclass(frozen=True)
class Calibration:
    """The calibrated baseline: its columns (the model's change per unit of each calibration
    parameter), the simulation ``m0`` they are measured around, at knob coordinates ``x0``, and the fit."""

    knobs: list[Knob]
    columns: list[Column]
    m0: np.ndarray
    x0: dict[str, float]
    solution: Solution
    jacobian: np.ndarray  # the knobs' columns at x0 (what the next calibration starts from)

    @property
    def residual(self) -> np.ndarray:
        return self.solution.fitted


def calibrate(problem: Problem, sim: Simulator, data: Sequence[RecordFeatures],
              base_effects: Mapping[str, Mapping[str, Any]], m0: np.ndarray, say: Callable[[str], None],
              jacobian: np.ndarray | None = None) -> Calibration:
    """Fit the calibration by Gauss-Newton on the replay (a load cell's resonance is far from linear in
    fn and zeta): the knobs' columns by finite differences once (or ``jacobian``, a previous
    calibration's), then Broyden's update from each step's own replay.  Steps are held within
    FAR_FROM_PRIOR prior widths of the preset (a knob pushed beyond them is a finding, or the sign of a
    missing effect: no reason to linearise there).

    Each linearisation's columns carry their knob's prior width around the point they are measured at,
    not around the preset: within the box above, the width bounds each step and every later fit's
    move (a candidate's, the proof's folds), and the preset does not pull.  Centring them on the preset
    (a Gaussian prior proper), a Levenberg-Marquardt accept rule, and recalibrating from this
    calibration's point were each tried and not kept (docs/diagnosis.md, Results)."""
    knobs = [k for k in KNOBS if sim.knob_applies(k)]
    width = np.array([k.prior_rel for k in knobs])
    x = np.zeros(len(knobs))
    if jacobian is None:
        say(f"calibration: {', '.join(k.path for k in knobs)}")
        h = 0.02
        moved = problem.model_many([({k.path: h}, None) for k in knobs])
        jacobian = np.column_stack([(m - m0) / h for m in moved]) if knobs else np.zeros((m0.size, 0))
    cols = _columns(knobs, jacobian, m0, problem.layout, data, base_effects)
    sol = problem.solve(m0, cols)
    for _ in range(GAUSS_NEWTON_STEPS):
        step = np.array([sol.value(k.path)[0] for k in knobs])
        x1 = np.clip(x + step, -FAR_FROM_PRIOR * width, FAR_FROM_PRIOR * width)
        dx = x1 - x
        if not np.any(np.abs(dx) > RELINEARISE):
            break
        say("re-linearising the calibration")
        m1 = problem.model({k.path: float(v) for k, v in zip(knobs, x1)})
        jacobian = jacobian + np.outer((m1 - m0) - jacobian @ dx, dx) / float(dx @ dx)  # Broyden
        x, m0 = x1, m1
        cols = _columns(knobs, jacobian, m0, problem.layout, data, base_effects)
        sol = problem.solve(m0, cols)
    return Calibration(knobs, cols, m0, {k.path: float(v) for k, v in zip(knobs, x)}, sol, jacobian)


def _columns(knobs: Sequence[Knob], jacobian: np.ndarray, m0: np.ndarray, layout: Layout,
             data: Sequence[RecordFeatures], base_effects: Mapping[str, Mapping[str, Any]]) -> list[Column]:
    """The knobs' columns, the discrepancy's and the sensitivities' (which scale the model itself)."""
    cols = [Column(k.path, jacobian[:, i], prior=k.prior_rel) for i, k in enumerate(knobs)]
    cols += discrepancy_columns(data, base_effects, layout, m0)
    for name, (channel, width) in GAINS.items():
        mask = np.zeros(m0.size, bool)
        mask[:layout.size] = layout.channel == CHANNELS.index(channel)
        if np.any(mask):
            cols.append(Column(name, np.where(mask, m0, 0.0), prior=width))
    return cols


def recalibrated(sim: Simulator, calibration: Calibration, sol: Solution) -> dict[str, dict[str, Any]]:
    """Each calibration parameter's value, standard error and prior; a finding where the data pushed
    it beyond FAR_FROM_PRIOR prior widths."""
    knobs, x0, cal = calibration.knobs, calibration.x0, calibration.columns
    out: dict[str, dict[str, Any]] = {}
    for k in knobs:
        x, sx = x0.get(k.path, 0.0) + sol.value(k.path)[0], sol.value(k.path)[1]
        prior, value = sim.knob_value(k), sim.knob_value(k, x)
        entry: dict[str, Any] = {"value": value, "std": sx if k.linear else value * sx, "prior": prior,
                                 "prior_rel": k.prior_rel}
        if abs(x) > FAR_FROM_PRIOR * k.prior_rel:
            how = (f"{value:.4g} instead of the preset's {prior:.4g}" if k.linear else
                   f"{math.exp(x):.2g}x the preset's ({prior:.4g} -> {value:.4g})")
            entry["finding"] = f"{k.path} is {how}, {abs(x) / k.prior_rel:.1f} prior widths away"
            if k.needs and not k.linear:
                entry["finding"] += f": {k.needs} is {'stronger' if x > 0 else 'weaker'} than the preset says"
        out[k.path] = entry
    for path in ("iron", "law", "amplifier"):
        parts = [c for c in cal if c.name.startswith(f"discrepancy.{path}.")]
        if not parts:
            continue
        # each coefficient in prior widths; the path's size is the largest
        widths = [abs(sol.value(c.name)[0]) / c.prior for c in parts]
        worst = int(np.argmax(widths))
        entry = {"value": widths[worst], "std": None, "prior": 0.0, "prior_rel": 1.0, "where": parts[worst].name,
                 "parameters": len(parts)}
        if widths[worst] > FAR_FROM_PRIOR:
            what = {"iron": "the iron (current to flux)", "law": "the force law (flux to force)",
                    "amplifier": "the current amplifier (command to current)"}[path]
            entry["finding"] = (f"{what} differs from the simulation beyond its prior: {parts[worst].name} is "
                                f"{widths[worst]:.1f} prior widths (a smooth discrepancy takes it; no parameter "
                                "of the preset reaches it)")
        out[f"discrepancy.{path}"] = entry
    return out
