"""Stage 1 of a diagnosis: calibrate the baseline simulation against the bench day.

What a bench engineer would calibrate, each against its prior from the preset (the knobs of
:mod:`.columns`: the load cell, the airgap, the magnet, the eddy currents' conductivities, the frame's
depth, the flux and force sensitivities), and the static loop itself: a real iron's loop is never the
preset material's, so at each rig and amplitude each harmonic of flux and force may move by one complex
number, the same at every frequency (what frequency does is left for the candidates to explain).  A
parameter the data push beyond FAR_FROM_PRIOR prior widths is a finding of its own.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from .columns import GAINS, KNOBS, Knob, Simulator
from .features import RecordFeatures
from .fit import Column, Problem, Solution
from .vector import CHANNELS, Layout

__all__ = ["Calibration", "calibrate", "recalibrated", "FAR_FROM_PRIOR", "STATIC_LOOP_PRIOR"]

#: A calibration parameter this many prior widths from its preset is reported as a finding.
FAR_FROM_PRIOR = 3.0
#: Re-linearise the calibration when a knob moved more than this (log factor).
RELINEARISE = 0.05
#: At most this many re-linearisations of the calibration.
GAUSS_NEWTON_STEPS = 4
#: Prior width of the static loop's recalibration, as a share of the channel's largest harmonic.
STATIC_LOOP_PRIOR = 0.05


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
    FAR_FROM_PRIOR prior widths (a knob pushed beyond them is a finding, or the sign of a missing
    effect: no reason to linearise there)."""
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
    """The knobs' columns, the static loop's and the sensitivities' (which scale the model itself)."""
    cols = [Column(k.path, jacobian[:, i], prior=k.prior_rel) for i, k in enumerate(knobs)]
    cols += static_loop_columns(data, base_effects, layout, m0)
    for name, (channel, width) in GAINS.items():
        mask = np.zeros(m0.size, bool)
        mask[:layout.size] = layout.channel == CHANNELS.index(channel)
        if np.any(mask):
            cols.append(Column(name, np.where(mask, m0, 0.0), prior=width))
    return cols


def static_loop_columns(data: Sequence[RecordFeatures], base_effects: Mapping[str, Mapping[str, Any]], layout: Layout,
                        m0: np.ndarray) -> list[Column]:
    """The baseline's static hysteresis, recalibrated without a form: at each rig and amplitude, each
    harmonic of the flux and of the force may move by one complex number, the same at every frequency.
    A real iron's loop is never the preset material's; what the rig's other physics does with
    frequency (eddy currents, the instrument, the channels' filters and delays) stays for the
    candidates to explain.  Only for rigs whose baseline has ``static_hysteresis``."""
    cols = []
    groups: dict[tuple[str, float], list[int]] = {}
    for r, f in enumerate(data):
        if "static_hysteresis" in base_effects.get(f.rig, {}):
            groups.setdefault((f.rig, round(f.current_pp_a, 6)), []).append(r)
    for (rig, amp), recs in groups.items():
        in_group = np.isin(layout.record, recs)
        for ch in ("flux_Wb", "force_N"):
            ci = CHANNELS.index(ch)
            for k in range(1, int(layout.harmonic.max(initial=0)) + 1):  # the DC is the force law's (knobs)
                for part in (0, 1):
                    sel = in_group & (layout.channel == ci) & (layout.harmonic == k) & (layout.part == part)
                    if not sel.any():
                        continue
                    v = np.zeros(m0.size)
                    v[np.flatnonzero(sel)] = 1.0
                    scale = float(np.max(layout.scale[in_group & (layout.channel == ci)]))
                    cols.append(Column(f"static_loop.{rig}@{amp:g}A.{ch}.k{k}.{'im' if part else 're'}", v,
                                       prior=STATIC_LOOP_PRIOR * scale))
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
    loop = [c for c in cal if c.name.startswith("static_loop.")]
    for c in cal:
        if c.name in GAINS:
            g, s = sol.value(c.name)
            entry = {"value": 1.0 + g, "std": s, "prior": 1.0, "prior_rel": c.prior}
            if abs(g) > FAR_FROM_PRIOR * (c.prior or 1.0):
                entry["finding"] = f"{c.name}: the channel reads {1 + g:.3g}x what the preset's sensitivity says"
            out[c.name] = entry
    if loop:
        shares = [abs(sol.value(c.name)[0]) / (c.prior / STATIC_LOOP_PRIOR) for c in loop]
        worst = int(np.argmax(shares))
        entry = {"value": shares[worst], "std": None, "prior": 0.0, "prior_rel": STATIC_LOOP_PRIOR,
                 "where": loop[worst].name, "parameters": len(loop)}
        if shares[worst] > FAR_FROM_PRIOR * STATIC_LOOP_PRIOR:
            entry["finding"] = (f"static_hysteresis: the loop differs from the preset material's by up to "
                                f"{100 * shares[worst]:.1f} % of the channel ({loop[worst].name})")
        out["static_hysteresis.loop"] = entry
    return out
