"""The force error of the paper's Eq. 5, before and after each correction (Secs. V-VII).

    Delta F = F_measured - F_model                                               (Eq. 5)

on the period-averaged waveform of one recording, three ways:

- ``before``: the measured force against the non-hysteretic MEC model (Eq. 1) of the measured
  current (the paper's Figs. 10b, 14b);
- ``instrument``: the measured force shifted back by the instrument's delay, which the method
  measures as force behind flux (Figs. 13b, 15b, 16; the paper shifts by 1.52 deg at 320 Hz);
- ``hysteresis``: that corrected force against the phase-delay model (Eq. 6), the current
  delayed by theta_hyst(f) (Fig. 19).

Figures of merit, all relative to the force range (max - min of the averaged measured force):
``max_abs`` = max |Delta F|, accuracy = 100 % x (1 - max |Delta F| / range) (Sec. VIII), the same
with the mean of Delta F removed (``ac``: what an AC-only piezoelectric instrument sees), and the
loop-eye height (Fig. 17): the vertical opening of the Delta F-current loop, at i = 0 with magnet
(where the k1 i term makes it largest: 2 k1 I sin(theta) for a pure delay), and the largest
opening anywhere without magnet (F ~ i^2 has no slope at i = 0, so the loop closes there; it
opens most near |i| = I / sqrt 2).

The period average is synchronous (:func:`.periodic.synchronous_average`): every whole period
of the record is resampled (cubic interpolation) at the same phases of the *estimated true*
frequency -- the generator and the ADC clocks differ by tens of ppm, so averaging at the nominal
frequency would smear the loops -- and the periods are averaged.  The figures thus measure the
model, not the sensor noise.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..config import load_rig
from ..errors import EstimationError
from ..physics import presets
from ..physics.phase_delay_model import PhaseDelayModel, delay_periodic
from .method import MethodDelays, check_channels, measure_delays, recording_name
from .periodic import PeriodAverage, synchronous_average
from .sense_coil import with_flux
from ..formats.recording import Recording

__all__ = ["loop_eye", "ForceError", "force_error", "phase_delay_model", "analytical_model", "ERROR_KINDS"]

ERROR_KINDS = ("before", "instrument", "hysteresis")


def loop_eye(current: np.ndarray, error: np.ndarray, *, at: float | None = None,
             n_grid: int = 401) -> tuple[float, float]:
    """Vertical opening of the loop ``error`` against ``current`` over one period.

    The period is split at the current's minimum and maximum into the rising and the falling
    branch; both are interpolated on a common current grid.  Returns (opening, current where it
    is taken): at ``at`` if given (e.g. 0 A), else where it is largest."""
    i, e = np.asarray(current, float), np.asarray(error, float)
    n = i.size
    lo, hi = int(np.argmin(i)), int(np.argmax(i))
    up = np.arange(lo, lo + (hi - lo) % n + 1) % n
    down = np.arange(hi, hi + (lo - hi) % n + 1) % n
    i_up, e_up = i[up], e[up]
    i_dn, e_dn = i[down][::-1], e[down][::-1]
    # the branches are monotonic for a sine-like current; keep them so for np.interp
    keep_up = np.concatenate(([True], np.diff(np.maximum.accumulate(i_up)) > 0))
    keep_dn = np.concatenate(([True], np.diff(np.maximum.accumulate(i_dn)) > 0))
    a, b = max(i_up.min(), i_dn.min()), min(i_up.max(), i_dn.max())
    if at is not None:
        if not a <= at <= b:
            raise ValueError(f"the loop does not reach i = {at:g} A (it spans {a:g} to {b:g} A)")
        grid = np.array([float(at)])
    else:
        margin = 0.01 * (b - a)  # the branches meet at the ends; stay off the turning points
        grid = np.linspace(a + margin, b - margin, n_grid)
    gap = np.abs(np.interp(grid, i_up[keep_up], e_up[keep_up]) - np.interp(grid, i_dn[keep_dn], e_dn[keep_dn]))
    j = int(np.argmax(gap))
    return float(gap[j]), float(grid[j])


def analytical_model(rig: str) -> PhaseDelayModel:
    """The paper's non-hysteretic analytical model (Eq. 1) of an E-core rig: the MEC with the
    preset's linear iron at the nominal airgap."""
    mec = presets.ecore_mec(load_rig(rig), linear_iron=True)
    return PhaseDelayModel.non_hysteretic(mec.force_coefficients(mec.geometry.airgap_m))


def phase_delay_model(rig: str, delays: list[MethodDelays]) -> PhaseDelayModel:
    """Eq. 6 for ``rig``: its Eq. 1 coefficients with theta_hyst (flux behind current) measured
    at each recording's nominal frequency (several recordings at one frequency are averaged)."""
    if not delays:
        raise EstimationError(f"{rig}: no measured delays to build the phase-delay model from")
    base = analytical_model(rig)
    f = np.array([d.nominal_frequency_hz for d in delays])
    th = np.array([d.theta_hyst_rad for d in delays])
    se = np.array([2 * np.pi * d.frequency_hz * d.delays_std_s["hysteresis"] for d in delays])
    return PhaseDelayModel.from_phases(base.coefficients, f, th, se)


@dataclass(frozen=True)
class ForceError:
    """Eq. 5 on the period average of one recording (see the module docstring)."""

    recording: str
    rig: str
    magnet: bool
    frequency_hz: float  # estimated true
    nominal_frequency_hz: float
    current_pp_a: float  # nominal
    instrument_delay_s: float
    theta_hyst_rad: float  # the model's, at the nominal frequency
    average: PeriodAverage
    force_n: np.ndarray  # measured (averaged)
    force_corrected_n: np.ndarray  # shifted back by the instrument delay
    model_n: np.ndarray  # Eq. 1
    hyst_model_n: np.ndarray  # Eq. 6
    errors_n: dict[str, np.ndarray] = field(default_factory=dict)

    @property
    def current_a(self) -> np.ndarray:
        return self.average.channels["current_A"]

    @property
    def force_range_n(self) -> float:
        return float(np.ptp(self.force_n))

    def max_abs_n(self, kind: str) -> float:
        return float(np.max(np.abs(self.errors_n[kind])))

    def accuracy_pct(self, kind: str) -> float:
        return 100.0 * (1.0 - self.max_abs_n(kind) / self.force_range_n)

    def offset_n(self, kind: str) -> float:
        """The DC part of Delta F (a static model error, or a force sensor's DC error)."""
        return float(np.mean(self.errors_n[kind]))

    def max_abs_ac_n(self, kind: str) -> float:
        """max |Delta F - mean Delta F|: the error a piezoelectric (AC-only) instrument can see."""
        e = self.errors_n[kind]
        return float(np.max(np.abs(e - e.mean())))

    def eye_n(self, kind: str) -> float:
        """Loop-eye height (N): at i = 0 with magnet, the largest opening without (Fig. 17)."""
        i = self.current_a
        at = 0.0 if self.magnet and i.min() < 0.0 < i.max() else None
        return loop_eye(i, self.errors_n[kind], at=at)[0]

    def summary(self) -> dict:
        rng = self.force_range_n
        return {
            "recording": self.recording, "rig": self.rig, "frequency_Hz": self.frequency_hz,
            "nominal_frequency_Hz": self.nominal_frequency_hz, "current_pp_A": self.current_pp_a,
            "periods_averaged": self.average.periods, "force_min_N": float(self.force_n.min()),
            "force_max_N": float(self.force_n.max()), "force_range_N": rng,
            "instrument_delay_s": self.instrument_delay_s,
            "instrument_phase_deg": 360.0 * self.frequency_hz * self.instrument_delay_s,
            "theta_hyst_deg": float(np.degrees(self.theta_hyst_rad)),
            "force_noise_rms_N": self.average.noise_rms.get("force_N"),
            "max_abs_error_N": {k: self.max_abs_n(k) for k in self.errors_n},
            "max_abs_error_pct": {k: 100 * self.max_abs_n(k) / rng for k in self.errors_n},
            "eye_height_N": {k: self.eye_n(k) for k in self.errors_n},
            "eye_height_pct": {k: 100 * self.eye_n(k) / rng for k in self.errors_n},
            "accuracy_pct": {k: self.accuracy_pct(k) for k in self.errors_n},
            "offset_N": {k: self.offset_n(k) for k in self.errors_n},
            "max_abs_ac_error_pct": {k: 100 * self.max_abs_ac_n(k) / rng for k in self.errors_n},
            "accuracy_ac_pct": {k: 100 * (1 - self.max_abs_ac_n(k) / rng) for k in self.errors_n},
        }


def force_error(rec: Recording, model: PhaseDelayModel, delays: MethodDelays | None = None, *,
                n_points: int = 1000) -> ForceError:
    """Eq. 5 for one E-core recording with the phase-delay ``model`` (Eq. 6) of its rig.

    ``delays`` (default: measured here) gives the true frequency and the instrument delay (force
    behind flux) by which the measured force is shifted back."""
    rec = with_flux(rec)
    d = measure_delays(rec) if delays is None else delays
    check_channels(rec, ("current_A", "force_N"))
    avg = synchronous_average(rec, d.frequency_hz, n_points, ("current_A", "flux_Wb", "force_N"))
    i, f_meas = avg.channels["current_A"], avg.channels["force_N"]
    tau = d.delays_s["instrument"]
    f_corr = delay_periodic(f_meas, -tau * d.frequency_hz)  # advance by the instrument delay
    eq1 = model.static_force(i)
    eq6 = model.force_period(i, rec.frequency_hz)
    errors = {"before": f_meas - eq1, "instrument": f_corr - eq1, "hysteresis": f_corr - eq6}
    return ForceError(recording_name(rec), rec.rig, d.harmonic == 1, d.frequency_hz, rec.frequency_hz,
                      rec.current_pp_a, tau, float(model.theta(rec.frequency_hz)), avg, f_meas, f_corr,
                      eq1, eq6, errors)
