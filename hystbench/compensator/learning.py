"""Iterative learning control for a periodic force reference, on the instrument-corrected error.

Each iteration measures the period-averaged force and compares it with the reference *as the
load cell should report it* (the reference through the instrument's response):

    e_k = F_measured - H_instr{F_ref}                       (measurement domain, every harmonic)

That maximum |e_k| over the period is the tracking error reported, beside the noise floor of the
same average (its alternating-sign average, see ``periodic``).  The update corrects the force the
model is asked for, with the instrument divided out harmonic by harmonic inside a band
(``band_hz``, by default 1.5 x the load cell's resonance: a model error there is what the
resonance amplifies most in the measurement, and dividing by H there is well conditioned):

    F_cmd,k+1 = F_cmd,k - gain * H_instr^-1{e_k}|band,      i_k+1 = model^-1(F_cmd,k+1)

so the model's inverse is the learning filter: it handles the quadratic law (and the affine one
with a magnet) and the actuator's phase lead, and the learning only has to remove what the model
misses.  Band-limiting keeps the averaged noise above the band out of the command.

Guard: the loop stops itself -- the caller switches the output off and raises
:class:`LearningStopped` with the reason -- when the error grows beyond ``diverge_ratio`` times
the best seen (and above twice the noise floor, so noise alone never trips it), when the
learned command would need more than the current limit or a force the actuator cannot make, or
when the measurement is not finite.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from ..errors import ConfigError
from ..physics.instrument import InstrumentModel
from .errors import LearningStopped, UnreachableReference
from .models import ForceModel
from .periodic import PeriodMeasurement, apply_response, resample
from .reference import ForceReference

__all__ = ["LearningConfig", "IterationReport", "LearningController"]


@dataclass(frozen=True)
class LearningConfig:
    """The learning loop's settings, checked here once, so a bad value is refused before anything
    is driven."""

    gain: float = 0.8
    iterations: int = 10
    band_hz: float | None = None  # the instrument is divided out up to here; None: 1.5 x its fn
    max_harmonic: int = 250
    diverge_ratio: float = 2.0
    target_ratio: float = 2.0  # tracking error / noise floor counted as "within the floor"

    def __post_init__(self) -> None:
        if not 0.0 < self.gain <= 1.5:
            raise ConfigError(f"learning gain must be in (0, 1.5], got {self.gain}")
        if self.iterations < 0 or self.max_harmonic < 1 or (self.band_hz is not None and not self.band_hz > 0) \
                or not self.diverge_ratio > 1:
            raise ConfigError("iterations >= 0, max_harmonic >= 1, band_hz > 0 and diverge_ratio > 1 are required, "
                              f"got {self.iterations}, {self.max_harmonic}, {self.band_hz}, {self.diverge_ratio}")


@dataclass(frozen=True)
class IterationReport:
    """How one iteration went against the noise floor: its line in the report, and what decides
    whether the loop goes on."""

    iteration: int  # 0: feed-forward only
    max_error_n: float  # max |e| over the averaged period
    rms_error_n: float
    error_pct: float  # of the reference's range
    noise_floor_n: float  # max |alternating average| of the same record
    ratio: float  # max_error / noise_floor
    peak_current_a: float
    periods: int
    status: str

    def as_dict(self) -> dict:
        return asdict(self)


class LearningController:
    """Holds the learned force command and the current table it maps to."""

    def __init__(self, model: ForceModel, reference: ForceReference, instrument: InstrumentModel,
                 current_limit_a: float, config: LearningConfig = LearningConfig()) -> None:
        self.model, self.reference, self.instrument = model, reference, instrument
        self.limit_a, self.config = float(current_limit_a), config
        self.frequency_hz = reference.frequency_hz
        self.command_force_n = reference.force_n.copy()
        self.current_a = self.current_for(self.command_force_n)  # UnreachableReference for a bad reference
        self.best_error_n = np.inf
        self.history: list[IterationReport] = []

    def current_for(self, force_n: np.ndarray, model: ForceModel | None = None) -> np.ndarray:
        """The current table for a force command (with ``model``, default the controller's),
        refused beyond the current limit."""
        model = model or self.model
        i = model.current_period(force_n, self.frequency_hz, current_limit_a=self.limit_a)
        peak = float(np.max(np.abs(i)))
        if peak > self.limit_a:
            lo, hi = model.law.reachable_n(self.limit_a)
            raise UnreachableReference(
                f"the reference ({force_n.min():.4g} to {force_n.max():.4g} N at {self.frequency_hz:g} Hz) needs a "
                f"peak current of {peak:.4g} A with the {model.kind} model, above the {self.limit_a:g} A limit; "
                f"reachable statically {lo:.4g} to {hi:.4g} N, a little less at speed (the iron's share and "
                "the eddy lead)", (lo, hi))
        return i

    def retarget(self, model: ForceModel) -> np.ndarray:
        """Keep the learned force command, map it through another model (the online stage's,
        after it followed the live delay); nothing changes if that is out of reach."""
        current = self.current_for(self.command_force_n, model)
        self.model, self.current_a = model, current
        return current

    @property
    def band_harmonic(self) -> int:
        band = self.config.band_hz if self.config.band_hz is not None else 1.5 * self.instrument.fn_hz
        return int(max(1, min(self.config.max_harmonic, np.floor(band / self.frequency_hz))))

    def error(self, m: PeriodMeasurement) -> np.ndarray:
        """e_k of the module docstring, on the measurement's points."""
        ref = resample(self.reference.force_n, m.channels["force_N"].size)
        return m.channels["force_N"] - apply_response(ref, m.frequency_hz, self.instrument.frequency_response)

    def assess(self, m: PeriodMeasurement, iteration: int) -> IterationReport:
        """The tracking error of one measurement (no update)."""
        e = self.error(m)
        floor = m.floor("force_N")
        mx = float(np.max(np.abs(e)))
        ok = np.isfinite(mx)
        ratio = mx / floor if floor > 0 else np.inf
        status = ("not finite" if not ok else
                  "within the noise floor" if ratio <= self.config.target_ratio else "tracking")
        rep = IterationReport(iteration, mx, float(np.sqrt(np.mean(e * e))), 100.0 * mx / np.ptp(self.reference.force_n),
                              floor, float(ratio), float(np.max(np.abs(self.current_a))), m.periods, status)
        self.history.append(rep)
        return rep

    def update(self, m: PeriodMeasurement) -> np.ndarray:
        """The next current table, or :class:`LearningStopped` (see the guard above)."""
        rep = self.history[-1] if self.history else self.assess(m, 0)
        if not np.isfinite(rep.max_error_n):
            raise LearningStopped("the measured force is not finite; learning stopped", self.history)
        noisy_limit = 2.0 * rep.noise_floor_n
        if rep.max_error_n > self.config.diverge_ratio * self.best_error_n and rep.max_error_n > noisy_limit:
            raise LearningStopped(
                f"diverging: the tracking error grew to {rep.max_error_n:.4g} N, more than {self.config.diverge_ratio:g}x "
                f"the best so far ({self.best_error_n:.4g} N); learning stopped", self.history)
        self.best_error_n = min(self.best_error_n, rep.max_error_n)
        e = self.error(m)
        e_true = apply_response(e, m.frequency_hz, self.instrument.frequency_response, inverse=True,
                                max_harmonic=self.band_harmonic)
        step = resample(e_true, self.command_force_n.size)
        candidate = self.command_force_n - self.config.gain * step
        try:
            current = self.current_for(candidate)
        except UnreachableReference as err:
            raise LearningStopped(f"the learned command is out of reach: {err}; learning stopped", self.history) from err
        self.command_force_n, self.current_a = candidate, current
        return current
