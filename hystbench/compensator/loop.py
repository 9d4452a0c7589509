"""The closed loop: feed-forward from a model, then (optionally) learning, on an :class:`Actuation`.

Iteration 0 plays the model's inverse of the reference; each further one measures, assesses,
updates (``learning``) and plays the new table.  Every measurement discards a settling time
after a new table (the iron's memory, the load cell's ringing: a few ms), then averages whole
periods at the generator's true frequency, found from its own output (``command_V``), aligned to
the table.  If the learning stops itself the output is switched off *before*
:class:`LearningStopped` propagates.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from ..analysis.periodic import estimate_frequency
from ..errors import ConfigError
from ..physics.instrument import InstrumentModel
from .actuation import Actuation
from .errors import CompensatorError, LearningStopped
from .learning import IterationReport, LearningConfig, LearningController
from .models import ForceModel
from .periodic import measure_period
from .reference import ForceReference

__all__ = ["LoopResult", "run_closed_loop", "MEASURE_CHANNELS", "MAX_MEASURE_S"]

MEASURE_CHANNELS = ("force_N", "current_A", "command_V")
#: The longest one measurement may take: each averages at least 4 periods, so a reference slower
#: than 4 / MAX_MEASURE_S Hz cannot be measured (and its sample counts would overflow).
MAX_MEASURE_S = 60.0


@dataclass
class LoopResult:
    """What the offline learning loop leaves: each iteration's report and the last table played."""

    history: list[IterationReport]
    current_a: np.ndarray  # the last table played
    command_force_n: np.ndarray  # the force the model was last asked for
    frequency_hz: float
    reached_at: int | None = None  # first iteration within target_ratio x the noise floor
    notes: list[str] = field(default_factory=list)

    def as_dict(self) -> dict:
        return {"frequency_Hz": self.frequency_hz, "reached_at": self.reached_at, "notes": list(self.notes),
                "iterations": [r.as_dict() for r in self.history],
                "peak_current_A": float(np.max(np.abs(self.current_a)))}


def run_closed_loop(actuation: Actuation, model: ForceModel, reference: ForceReference, instrument: InstrumentModel,
                    *, learn: bool = True, config: LearningConfig = LearningConfig(), settle_s: float | None = None,
                    measure_s: float = 0.25, n_points: int = 1000,
                    on_iteration: Callable[[IterationReport], None] | None = None) -> LoopResult:
    """Run the loop (see the module docstring); the output is left on unless learning stopped."""
    f = reference.frequency_hz
    if not 0 < measure_s <= MAX_MEASURE_S:
        raise ConfigError(f"measure_s must be in (0, {MAX_MEASURE_S:g}] s, got {measure_s!r}")
    if 4.0 / f > MAX_MEASURE_S:
        raise CompensatorError(f"a reference at {f:g} Hz needs {4.0 / f:.4g} s per measurement (4 periods), more "
                               f"than {MAX_MEASURE_S:g} s; its frequency must be at least {4.0 / MAX_MEASURE_S:g} Hz")
    ctrl = LearningController(model, reference, instrument, actuation.current_limit_a, config)
    settle = int(round((settle_s if settle_s is not None else max(0.05, 4.0 / f)) * actuation.fs_hz))
    n_meas = int(round(max(measure_s, 4.0 / f) * actuation.fs_hz))
    actuation.set_waveform(ctrl.current_a, f)
    last = config.iterations if learn else 0
    reached = None
    for k in range(last + 1):
        actuation.read(settle)
        block = actuation.read(n_meas)
        chans = {c: np.asarray(block.channels[c], float) for c in MEASURE_CHANNELS}
        f_true = estimate_frequency(chans["command_V"], actuation.fs_hz, f)
        m = measure_period(chans, actuation.fs_hz, f_true, ctrl.current_a, n_points=n_points)
        rep = ctrl.assess(m, k)
        if on_iteration is not None:
            on_iteration(rep)
        if reached is None and rep.ratio <= config.target_ratio:
            reached = k
        if k == last:
            break
        try:
            table = ctrl.update(m)
        except LearningStopped:
            actuation.output_off()
            raise
        actuation.set_waveform(table, f)
    return LoopResult(ctrl.history, ctrl.current_a, ctrl.command_force_n, f, reached,
                      [f"driven through {actuation.name}"])
