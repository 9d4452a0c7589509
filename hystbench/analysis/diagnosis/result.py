"""What a diagnosis says: the stable ``hystbench diagnose --json`` document and what the report draws.

The keys are a public interface (issue 13): scripts read them, so a key is added, never renamed.
Every number is finite or ``None`` (JSON has no NaN).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Mapping

import numpy as np

__all__ = ["Candidate", "Diagnosis", "Limit", "Loops", "json_number"]


def json_number(x: Any) -> float | None:
    """A float for JSON: ``None`` for NaN or infinity (json.dumps(allow_nan=False) must pass)."""
    if x is None:
        return None
    v = float(x)
    return v if math.isfinite(v) else None


@dataclass(frozen=True)
class Candidate:
    """One candidate effect scored against the (recalibrated) baseline in one selection round."""

    name: str
    score: float  # BIC(baseline) - BIC(baseline + this effect): > 0 means the effect explains more than it costs
    parameters: Mapping[str, tuple[float, float]]  # catalogue parameter -> (value, standard error)
    round: int = 1
    held_out_gain: float | None = None  # for a decisive score: how much better, modelled, it predicts its signature held out (median fold)
    #: the share of what it does that is its own ("own": what no column it was scored against can make,
    #: in its most distinctive combination), then the share of that each group of those columns alone
    #: can make, largest first (select.mimicry)
    mimicry: Mapping[str, float] = field(default_factory=dict)
    #: how much better it predicts its signature's held-out total (every fold's numbers pooled; of a searched mode's two
    #: proofs, the worse), beside held_out_gain: a ratio, as held_out_gain
    held_out_total: float | None = None

    def own_text(self) -> str:
        """What it does that the baseline cannot, in words: ``"1.5e-06 its own, 99.8 % within the
        calibration's knobs"`` (empty when not measured)."""
        others = [(k, v) for k, v in self.mimicry.items() if k != "own"]
        if "own" not in self.mimicry:
            return ""
        text = f"{self.mimicry['own']:.2g} its own"
        return text + (f", {100 * others[0][1]:.1f} % within {others[0][0]}" if others else "")

    def to_json(self) -> dict[str, Any]:
        return {"name": self.name, "score": json_number(self.score), "round": self.round,
                "held_out_gain": json_number(self.held_out_gain), "held_out_total": json_number(self.held_out_total),
                "mimicry": {k: json_number(v) for k, v in self.mimicry.items()},
                "parameters": {k: {"value": json_number(v), "std": json_number(s)} for k, (v, s) in self.parameters.items()}}


@dataclass(frozen=True)
class Limit:
    """The size of one parameter of one effect at which the day would name it (.limits): decided from
    ``value`` up, or, ``at_most``, for a parameter whose size is its inverse (a time constant, a
    stiffness), from 0 up to ``value``; ``either_sign``: of either sign (a drift that falls or rises);
    ``in_range``: the catalogue's range reaches it."""

    effect: str
    param: str
    value: float
    unit: str
    at_most: bool
    in_range: bool
    #: what the limit leaves out, when something (a high-pass's DC over a whole day)
    note: str = ""
    either_sign: bool = False
    #: where the day sees it: (operating point, share of what the baseline cannot make of it), largest first
    seen_at: tuple[tuple[str, float], ...] = ()

    def bound(self) -> str:
        """``">= 7.3e-07 s"``, ``">= 0.08 K/s either way"`` or ``"<= 44 s"``; why there is none, out of range."""
        if not self.in_range:
            text = "none the catalogue's range reaches"
        else:
            text = f"{'<=' if self.at_most else '>='} {self.value:.2g}{' ' + self.unit if self.unit else ''}"
            text += " either way" if self.either_sign and not self.at_most else ""
        return text + (f" ({self.note})" if self.note else "")

    def text(self) -> str:
        """``"channel_skew current_A >= 7.3e-07 s"``."""
        return f"{self.effect} {self.param} {self.bound()}"

    def to_json(self) -> dict[str, Any]:
        return {"value": json_number(self.value), "unit": self.unit, "at_most": self.at_most,
                "either_sign": self.either_sign, "in_range": self.in_range, "note": self.note,
                "seen_at": {k: json_number(v) for k, v in self.seen_at}}


@dataclass(frozen=True)
class Loops:
    """One held-out recording's period, measured and predicted before/after (the report's loop figure)."""

    recording: str
    rig: str
    frequency_hz: float
    current_pp_a: float
    phase: np.ndarray  # cycles, one period
    measured: Mapping[str, np.ndarray]  # channel -> one period
    before: Mapping[str, np.ndarray]  # the calibrated baseline's prediction
    after: Mapping[str, np.ndarray]  # with the named effects


@dataclass
class Diagnosis:
    """The whole answer; :meth:`to_json` is the ``--json`` document."""

    effect: str | None
    effects: list[str]
    candidates: list[Candidate]
    parameters: dict[str, dict[str, tuple[float, float]]]  # effect -> param -> (value, std)
    recalibrated: dict[str, dict[str, Any]]  # "effect.param" or "preset.key" -> {value, std, prior, finding?}
    located: dict[str, Any]  # the issue's `located` keys (channels, harmonics, frequencies_Hz, ...)
    residual_before: float  # held-out rms residual, units of the noise floor
    residual_after: float
    noise_floor: dict[str, float]  # per channel: the period average's noise floor (channel units)
    seconds: float
    baseline: list[str] = field(default_factory=list)
    candidates_considered: list[str] = field(default_factory=list)
    findings: list[str] = field(default_factory=list)  # sentences: priors pushed far, what could not be located
    warnings: list[str] = field(default_factory=list)
    recordings: int = 0
    rigs: list[str] = field(default_factory=list)
    loops: Loops | None = None
    grid: Any = None  # the locate heat map's data (reports draw it)
    #: per named effect, the proof in its own signature: the held-out residual (model-error sigmas) on
    #: the numbers it moves, before and after it was modelled, and the median fold's improvement (what decides)
    signature: dict[str, dict[str, float]] = field(default_factory=dict)
    #: decisive effects the held-out proof refused, with their numbers
    suspects: list[Candidate] = field(default_factory=list)
    #: what the day can decide: each candidate parameter's size from which it would be expected to name it (.limits)
    limits: list[Limit] = field(default_factory=list)

    @property
    def improvement(self) -> float:
        if not (self.residual_after > 0 and math.isfinite(self.residual_before)):
            return math.nan
        return self.residual_before / self.residual_after

    def to_json(self) -> dict[str, Any]:
        return {
            "effect": self.effect,
            "effects": list(self.effects),
            "candidates": [c.to_json() for c in self.candidates],
            "parameters": {e: {p: {"value": json_number(v), "std": json_number(s)} for p, (v, s) in ps.items()}
                           for e, ps in self.parameters.items()},
            "recalibrated": {k: {kk: (json_number(vv) if isinstance(vv, (int, float, np.floating)) else vv)
                                  for kk, vv in v.items()} for k, v in self.recalibrated.items()},
            "located": self.located,
            "residual_before": json_number(self.residual_before),
            "residual_after": json_number(self.residual_after),
            "improvement": json_number(self.improvement),
            "noise_floor": {k: json_number(v) for k, v in self.noise_floor.items()},
            "seconds": json_number(self.seconds),
            "baseline": list(self.baseline),
            "candidates_considered": list(self.candidates_considered),
            "findings": list(self.findings),
            "warnings": list(self.warnings),
            "recordings": self.recordings,
            "rigs": list(self.rigs),
            "signature": {e: {k: json_number(v) for k, v in sig.items()} for e, sig in self.signature.items()},
            "suspects": [c.to_json() for c in self.suspects],
            "limits": self.limits_json(),
        }

    def limits_json(self) -> dict[str, dict[str, Any]]:
        """effect -> parameter -> its limit (:meth:`Limit.to_json`)."""
        return {e: {lim.param: lim.to_json() for lim in self.limits if lim.effect == e}
                for e in dict.fromkeys(lim.effect for lim in self.limits)}
