"""The online compensator: follows the live hysteresis-delay estimate and re-shapes the current.

It has the pipeline's compensator interface (``acquisition.pipeline.Compensator``):
``update(estimate, window=None) -> CompensatorUpdate | None``, where ``estimate`` is a
:class:`~hystbench.messages.Estimate` of one window (``frequency_hz``, ``delays_s['hysteresis']`` =
flux behind current, ``error``).  The update's ``state`` is published on the ``compensator`` topic;
when the update carries ``waveform_a`` (one period of current, played at ``frequency_hz``) the hook
uploads it to the source.

Following the live theta_hyst (smoothed, exponential weight ``smoothing``):

- the paper's model takes it as its theta at the operating frequency (Eq. 6 as the paper uses it);
- our model compares it with the flux lag it predicts for the current it commands; a difference
  is put into its eddy time constant tau (the rate-dependent part: a warming core conducts less,
  and tau follows the iron's conductivity), tau += dtheta / (2 pi f).

The table is recomputed and re-sent only when the theta used moves by more than ``retune_deg``
(so estimation noise does not keep the generator busy).

Learning online (``learning`` given): each estimate then comes with its window of samples (a
:class:`~hystbench.blocks.SampleBlock`); a window played entirely with the last table sent (its ``table`` count is the one that table gets when the
source applies it; a window of an older table, or of someone else's command, is skipped) is averaged over its whole periods (:func:`~.periodic.measure_period`, aligned to the table by
``command_V``) and handed to the same :class:`~.learning.LearningController` as the offline loop,
which returns the next table.  It is repetitive control: it runs as long as the stage does
(``LearningConfig.iterations`` bounds only the offline loop).  If
the controller stops itself (diverging, out of reach, not finite) the update asks for the output
off (``output_off``, which the hook applies first) and the stage sends nothing more.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from ..blocks import SampleBlock
from ..messages import CompensatorUpdate, Estimate
from ..physics.instrument import InstrumentModel
from .errors import LearningStopped, UnreachableReference
from .hysteresis_eddy import HysteresisEddyModel
from .learning import LearningConfig, LearningController
from .models import ForceModel, PaperModel
from .periodic import measure_period
from .reference import ForceReference

__all__ = ["CompensatorStage"]


class CompensatorStage:
    """The online compensator of the module docstring: the pipeline calls its :meth:`update`."""

    def __init__(self, model: ForceModel, reference: ForceReference, *, current_limit_a: float,
                 smoothing: float = 0.3, retune_deg: float = 0.02, learning: LearningConfig | None = None,
                 instrument: InstrumentModel | None = None) -> None:
        if not 0 < smoothing <= 1:
            raise ValueError(f"smoothing must be in (0, 1], got {smoothing}")
        if learning is not None and instrument is None:
            raise ValueError("learning needs the force instrument's model (instrument=)")
        self.model, self.reference = model, reference
        self.limit_a, self.smoothing, self.retune_rad = float(current_limit_a), float(smoothing), math.radians(retune_deg)
        self.theta_live: float | None = None
        self.theta_used: float | None = None
        self.updates = 0  # tables sent
        self.estimates = 0
        self.status = "starting"
        self.learner = None if learning is None else LearningController(model, reference, instrument, self.limit_a, learning)
        self.learns = self.learner is not None  # the pipeline's hook then hands over each window's samples
        self.stopped = False
        self.current_a = self._table(model)
        self._table_expected = -1  # the source's table count once it plays the last table sent

    def _model_theta(self) -> float:
        f = self.reference.frequency_hz
        if isinstance(self.model, PaperModel):
            return self.model.theta(f)
        if isinstance(self.model, HysteresisEddyModel):
            return self.model.flux_lag_rad(self.current_a, f)
        return 0.0

    def _follow(self, theta: float) -> None:
        """Move the model to ``theta``; nothing changes if its table would be out of reach."""
        f = self.reference.frequency_hz
        model = self.model
        if isinstance(model, PaperModel):
            model = model.with_theta(f, theta)
        elif isinstance(model, HysteresisEddyModel):
            tau = max(0.0, model.tau_s + (theta - self._model_theta()) / (2 * math.pi * f))
            model = replace(model, tau_s=tau)
            if "iron" in self.model.__dict__:  # same iron: keep its built tables
                model.__dict__["iron"] = self.model.__dict__["iron"]
        self.current_a = self._table(model)  # UnreachableReference: the stage is left as it was
        self.model, self.theta_used = model, theta

    def _table(self, model: ForceModel) -> np.ndarray:
        """The current period for the reference (or, learning, for the learned force command)."""
        if self.learner is None:
            return model.current_period(self.reference.force_n, self.reference.frequency_hz,
                                        current_limit_a=self.limit_a)
        return self.learner.retarget(model)

    def _learn(self, estimate: Estimate, window: SampleBlock | None) -> bool:
        """One learning step on the estimate's window, if it was played with the last table; True
        when it gave a new table.  LearningStopped propagates."""
        if self.learner is None or window is None or window.n == 0 or estimate.table != self._table_expected:
            return False  # another waveform (ours not yet applied, or someone else's command) played
        chans = {c: np.asarray(x, float) for c, x in window.channels.items()
                 if c in ("force_N", "current_A", "command_V")}
        ref = "command_V" if "command_V" in chans else "current_A"
        m = measure_period(chans, window.fs_hz, estimate.frequency_hz, self.current_a, reference=ref)
        self.learner.assess(m, len(self.learner.history))
        self.current_a = self.learner.update(m)
        self.status = "learning"
        return True

    def update(self, estimate: Estimate, window: SampleBlock | None = None) -> CompensatorUpdate | None:
        """One estimate (and, learning, its window of samples) in, the update out: the state, and
        the new table when it changed (or the output off, when the learning stopped itself)."""
        if self.stopped:
            return None
        if estimate.error:
            self.status = f"waiting: estimate refused ({estimate.error})"
            return None
        delay = estimate.delays_s.get("hysteresis", math.nan)
        f_est = estimate.frequency_hz if math.isfinite(estimate.frequency_hz) else self.reference.frequency_hz
        if not math.isfinite(delay):
            self.status = "waiting: estimate without a hysteresis delay"
            return None
        self.estimates += 1
        theta = 2 * math.pi * f_est * delay
        self.theta_live = theta if self.theta_live is None else (
            (1 - self.smoothing) * self.theta_live + self.smoothing * theta)
        send = self.updates == 0  # the first table goes out with the first estimate
        if self.theta_used is None or abs(self.theta_live - self.theta_used) > self.retune_rad:
            try:
                self._follow(self.theta_live)
                send = True
                self.status = "following"
            except UnreachableReference as err:
                self.status = f"holding the last table: {err}"
        if not send:
            try:
                send = self._learn(estimate, window)
            except LearningStopped as err:
                self.stopped = True
                self.status = f"stopped, output off: {err}"
                return CompensatorUpdate(self.state(), output_off=True)
        if send:
            self.updates += 1
            # the source applies sends in order: each moves its count on by one
            self._table_expected = max(self._table_expected, estimate.table) + 1
        if not send:
            return CompensatorUpdate(self.state())
        return CompensatorUpdate(self.state(), waveform_a=self.current_a.copy(),
                                 frequency_hz=self.reference.frequency_hz)

    def state(self) -> dict:
        th_model = self._model_theta()
        out = {"model": self.model.kind, "frequency_hz": self.reference.frequency_hz,
               "reference": self.reference.description, "status": self.status,
               "theta_live_deg": None if self.theta_live is None else math.degrees(self.theta_live),
               "theta_model_deg": math.degrees(th_model), "peak_current_a": float(np.max(np.abs(self.current_a))),
               "tables_sent": self.updates, "estimates": self.estimates}
        if isinstance(self.model, HysteresisEddyModel):
            out["tau_s"] = self.model.tau_s
        if self.learner is not None and self.learner.history:
            rep = self.learner.history[-1]
            out["learning"] = {"iteration": rep.iteration, "error_n": rep.max_error_n,
                               "noise_floor_n": rep.noise_floor_n, "ratio": rep.ratio, "status": rep.status}
        return out
