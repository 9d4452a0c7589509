"""The one interface of a force model, the paper's two models, and a model's force as the load cell
reports it: what the fitting (:mod:`.models`), the choice of the best description (:mod:`.choice`)
and its identification (:mod:`.identify`) all need, below all three so none of them imports another
to reach it.

- :class:`ForceModel`: one period of current in, one period of force out, and back;
- :class:`NonHysteretic` (the paper's Eq. 1) and :class:`PaperModel` (Eq. 6, :func:`paper_model`
  from a sweep's theta_hyst);
- :func:`predict_measured` and :func:`force_error`: a model through the instrument's response, and
  its error against one recording (Eq. 5 in the measurement domain).

:mod:`.models` re-exports every name here, so ``compensator.models`` stays where users find them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Protocol, Sequence, runtime_checkable

import numpy as np

from ..physics.instrument import InstrumentModel
from ..physics.phase_delay_model import PhaseDelayModel
from .data import PeriodData
from .errors import CompensatorError
from .periodic import apply_response, denoise, shift
from .static import StaticLaw

__all__ = ["ForceModel", "NonHysteretic", "PaperModel", "paper_model", "predict_measured", "force_error"]


@runtime_checkable
class ForceModel(Protocol):
    """One period of current in, one period of force out, and back: all that fitting, prediction and
    the compensator ask of a model, whichever it is."""

    kind: str
    name: str
    law: StaticLaw

    def force_period(self, current_a: np.ndarray, frequency_hz: float) -> np.ndarray: ...

    def current_period(self, force_n: np.ndarray, frequency_hz: float,
                       current_limit_a: float | None = None) -> np.ndarray: ...

    def to_dict(self) -> dict: ...


@dataclass(frozen=True)
class NonHysteretic:
    """Eq. 1: the force follows the current through the static law, with no delay."""

    law: StaticLaw
    kind: str = "nonhysteretic"
    name: str = "eq1_mec"

    def force_period(self, current_a: np.ndarray, frequency_hz: float) -> np.ndarray:
        """The static law sample by sample: the frequency does not matter to Eq. 1."""
        return self.law.force(current_a)

    def current_period(self, force_n: np.ndarray, frequency_hz: float,
                       current_limit_a: float | None = None) -> np.ndarray:
        """The static inverse: the feed-forward that ignores hysteresis (the paper's baseline)."""
        return self.law.invert(force_n, current_limit_a=current_limit_a)

    def to_dict(self) -> dict:
        return {"kind": self.kind, "name": self.name, "law": self.law.to_dict()}


@dataclass(frozen=True)
class PaperModel:
    """Eq. 6: the current delayed by theta_hyst(f) as a whole, then Eq. 1; its inverse advances
    the static inverse by theta (the phase lead for the actuator's delay)."""

    law: StaticLaw
    frequency_hz: tuple[float, ...]
    theta_rad: tuple[float, ...]
    kind: str = "paper"
    name: str = "eq6_phase_delay"

    @property
    def phase(self) -> PhaseDelayModel:
        return PhaseDelayModel.from_phases(self.law.coefficients, self.frequency_hz, self.theta_rad)

    def theta(self, frequency_hz: float) -> float:
        return float(self.phase.theta(float(frequency_hz)))

    def force_period(self, current_a: np.ndarray, frequency_hz: float) -> np.ndarray:
        """Eq. 6: the period delayed by theta(f) as a whole, then the static law."""
        return self.law.force(shift(current_a, self.theta(frequency_hz) / (2 * np.pi)))

    def current_period(self, force_n: np.ndarray, frequency_hz: float,
                       current_limit_a: float | None = None) -> np.ndarray:
        """The static inverse advanced by theta(f): the phase lead that cancels the delay of Eq. 6."""
        j = self.law.invert(force_n, current_limit_a=current_limit_a)
        return shift(j, -self.theta(frequency_hz) / (2 * np.pi))

    def with_theta(self, frequency_hz: float, theta_rad: float) -> "PaperModel":
        """The model with theta at ``frequency_hz`` replaced (the live estimate)."""
        f, th = list(self.frequency_hz), list(self.theta_rad)
        near = [k for k, x in enumerate(f) if abs(x - frequency_hz) <= 1e-3 * frequency_hz]
        if near:
            th[near[0]] = float(theta_rad)
        else:
            f.append(float(frequency_hz))
            th.append(float(theta_rad))
        order = np.argsort(f)
        return replace(self, frequency_hz=tuple(float(f[k]) for k in order),
                       theta_rad=tuple(float(th[k]) for k in order))

    def to_dict(self) -> dict:
        return {"kind": self.kind, "name": self.name, "law": self.law.to_dict(),
                "frequency_Hz": list(self.frequency_hz), "theta_hyst_rad": list(self.theta_rad)}


def paper_model(points: Sequence[PeriodData], law: StaticLaw, *, kind: str = "paper") -> PaperModel:
    """Eq. 6 from a sweep: ``law`` with the theta_hyst measured at each frequency (several amplitudes
    at one frequency: their mean)."""
    th = [(p.nominal_frequency_hz, p.theta_hyst_rad) for p in points if np.isfinite(p.theta_hyst_rad)]
    if not th:
        raise CompensatorError("no theta_hyst measured in the sweep; the paper's Eq. 6 needs it")
    pm = PhaseDelayModel.from_phases(law.coefficients, [f for f, _ in th], [t for _, t in th])
    return PaperModel(law, tuple(map(float, pm.frequency_hz)), tuple(map(float, pm.theta_rad)), kind=kind)


# --- what the load cell reports ------------------------------------------------------------------
def predict_measured(model: ForceModel, current_a: np.ndarray, frequency_hz: float, instrument: InstrumentModel,
                     *, current_noise_a: float = math.nan) -> np.ndarray:
    """The force the load cell would report for one period of measured current: the model's
    force through the instrument.  ``current_noise_a`` (noise of one point of the averaged
    current) lets :func:`~.periodic.denoise` drop harmonics that are only noise first."""
    i = denoise(current_a, current_noise_a)
    return apply_response(model.force_period(i, frequency_hz), frequency_hz, instrument.frequency_response)


def force_error(model: ForceModel, point: PeriodData, instrument: InstrumentModel) -> dict:
    """Eq. 5 in the measurement domain for one recording: measured minus predicted-as-measured,
    with the paper's accuracy 100 % (1 - max|dF| / range) on the period average."""
    pred = predict_measured(model, point.current_a, point.frequency_hz, instrument,
                            current_noise_a=point.average_noise_a())
    err = np.asarray(point.force_n) - pred
    rng = point.force_range_n
    return {"recording": point.name, "model": model.kind, "frequency_Hz": point.nominal_frequency_hz,
            "current_pp_A": point.current_pp_a, "force_range_N": rng, "max_abs_error_N": float(np.max(np.abs(err))),
            "accuracy_pct": 100.0 * (1.0 - float(np.max(np.abs(err))) / rng),
            "mean_error_N": float(np.mean(err)), "error_N": err, "predicted_N": pred}
