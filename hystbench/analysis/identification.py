"""Identification from sweeps: the force instrument from a voice coil (paper Sec. IV, Figs. 7-9)
and theta_hyst of an E-core (Secs. V-VII).

Instrument: a stepped-sine sweep of a voice coil, one recording per frequency, gives
H(f) = force / current (a joint sine fit per point, with standard errors).  The paper's model,
K x H_mech x H_LPF (two second-order low-passes: fn, zeta_n of the load cell and frame, f0, zeta_0
of the charge amplifier), is fitted to log H = ln|H| + j arg H by ``scipy.optimize.least_squares``,
K the low-frequency force constant.  The weights are the sine fits' standard errors with a floor
(0.5 % in magnitude, 0.25 deg in phase) for what the model leaves out (the frame's small modes near
850 and 1175 Hz, Fig. 7c); the parameter uncertainties are scaled by the fit's reduced chi^2, so
they include that misfit.

Magnet eddy currents: a conducting magnet (NdFeB, SmCo) lags the force beyond the instrument.
Fitting the two low-passes to such data would absorb that lag, so -- as the paper does -- the
ferrite coil's fit is the benchmark, and every other coil's phase is compared with it: the
residual phase below the resonance is fitted with a first-order lag -atan(2 pi f tau) and its
lag at 3 kHz (the paper: about 15 deg) is reported; above 3 deg and 5 standard errors it is
flagged as "eddy currents in the magnet".
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike
from scipy.optimize import least_squares

from ..config import load_rig
from ..errors import EstimationError, RecordingError
from ..physics import presets
from ..physics.instrument import InstrumentModel
from .estimation import estimation_errors, phase_delay
from .method import check_channels, check_fit_quality, recording_name
from ..formats.recording import Recording, read_sweep
from .sense_coil import with_flux

__all__ = ["FrequencyResponse", "InstrumentFit", "EddyLag", "frequency_response", "fit_instrument",
           "eddy_lag", "is_benchmark", "read_sweeps", "preset_instrument", "EDDY_CHECK_HZ", "EDDY_MIN_DEG",
           "MIN_SAMPLES_PER_PERIOD"]

MAG_FLOOR = 0.005  # ln|H| (0.5 %)
PHASE_FLOOR_RAD = np.radians(0.25)
EDDY_CHECK_HZ = 3000.0  # where the paper quotes the magnets' extra lag (Fig. 7c)
EDDY_MIN_DEG = 3.0  # an extra lag above this (and 5 standard errors) is flagged
PARAMS = ("force_constant_N_per_A", "fn_Hz", "zeta_n", "f0_Hz", "zeta_0")
MIN_SAMPLES_PER_PERIOD = 10  # a stepped-sine point at f needs fs >= 10 f


def _wrap(x):
    return np.angle(np.exp(1j * np.asarray(x)))


@dataclass(frozen=True)
class FrequencyResponse:
    """Force per current of one voice-coil sweep, one point per recording, sorted by frequency."""

    rig: str
    frequency_hz: np.ndarray  # estimated true frequencies
    h: np.ndarray  # complex, N/A
    ln_mag_se: np.ndarray  # standard error of ln|H|
    phase_se_rad: np.ndarray
    recordings: tuple[str, ...]

    @property
    def phase_rad(self) -> np.ndarray:
        """arg H, wrapped to (-pi, pi]."""
        return np.angle(self.h)


def frequency_response(recs: list[Recording], *, dropped: list | None = None) -> FrequencyResponse:
    """H(f) = force / current of a voice-coil sweep (one recording per frequency).

    A point the method refuses (e.g. the force lost in the noise far above the resonance) raises
    its EstimationError; with a ``dropped`` list given, it is left out and ``(recording, reason)``
    appended there instead, so the caller can report it."""
    if not recs:
        raise EstimationError("no recordings: a frequency response needs a sweep")
    rigs = sorted({r.rig for r in recs})
    if len(rigs) > 1:
        raise EstimationError(f"recordings of several rigs ({', '.join(rigs)}); a sweep is one rig")
    if load_rig(rigs[0]).get("actuator") != "voicecoil":
        raise EstimationError(f"{recording_name(recs[0])}: rig {rigs[0]!r} is not a voice coil; the instrument "
                              "is identified from a voice-coil sweep")
    rows = []
    for rec in recs:
        where = recording_name(rec)
        try:
            if rec.fs_hz < MIN_SAMPLES_PER_PERIOD * rec.frequency_hz:
                raise EstimationError(
                    f"{where}: {rec.fs_hz / rec.frequency_hz:.1f} samples per period; a response point needs "
                    f">= {MIN_SAMPLES_PER_PERIOD} (nearer the Nyquist frequency an ADC's anti-alias filter, and "
                    "the simulator's discretised instrument, bend the phase)")
            ch = check_channels(rec, ("current_A", "force_N"))
            with estimation_errors(where):
                pd = phase_delay(ch["current_A"], ch["force_N"], rec.fs_hz, rec.frequency_hz)
            f = float(pd.frequency_hz)
            check_fit_quality(rec, f, {"current_A": (pd.x, 1), "force_N": (pd.y, 1)})
        except EstimationError as err:
            if dropped is None:
                raise
            dropped.append((where, str(err)))
            continue
        ai, af = float(pd.x.amplitude[0]), float(pd.y.amplitude[0])
        ln_se = float(np.hypot(pd.x.amplitude_se[0] / ai, pd.y.amplitude_se[0] / af))
        rows.append((f, af / ai * np.exp(-1j * float(pd.phase_rad)), ln_se, float(pd.phase_se_rad), where))
    if not rows:
        raise EstimationError(f"{rigs[0]} sweep: no usable recording ({len(recs)} refused)")
    rows.sort(key=lambda r: r[0])
    f, h, ln_se, ph_se, names = zip(*rows)
    if len(set(np.round(f, 9))) < len(f):
        raise EstimationError(f"{rigs[0]} sweep: two recordings at the same frequency")
    return FrequencyResponse(rigs[0], np.array(f), np.array(h), np.array(ln_se), np.array(ph_se), tuple(names))


def _model_h(p: np.ndarray, f: np.ndarray) -> np.ndarray:
    k, fn, zn, f0, z0 = np.exp(p)
    xn, x0 = f / fn, f / f0
    return k / ((1 - xn * xn + 2j * zn * xn) * (1 - x0 * x0 + 2j * z0 * x0))


@dataclass(frozen=True)
class InstrumentFit:
    """The paper's two-filter instrument model fitted to one voice-coil frequency response."""

    rig: str
    params: dict[str, float]
    std: dict[str, float]
    rms_phase_residual_deg: float
    rms_mag_residual_pct: float
    reduced_chi2: float
    response: FrequencyResponse
    cov_log: np.ndarray = field(repr=False, default_factory=lambda: np.zeros((5, 5)))  # of ln(params)

    @property
    def model(self) -> InstrumentModel:
        p = self.params
        return InstrumentModel(fn_hz=p["fn_Hz"], zeta_n=p["zeta_n"], f0_hz=p["f0_Hz"], zeta_0=p["zeta_0"])

    def phase_deg(self, frequency_hz: ArrayLike) -> np.ndarray:
        """Phase of the fitted model (negative: the measured force lags), degrees."""
        return self.model.phase_deg(frequency_hz)

    def phase_std_deg(self, frequency_hz: float) -> float:
        """Standard error of :meth:`phase_deg` at one frequency (from the parameter covariance)."""
        p = np.log([self.params[k] for k in PARAMS])
        grad = np.zeros(p.size)
        f = np.array([float(frequency_hz)])
        for j in range(p.size):
            dp = np.zeros(p.size)
            dp[j] = 1e-6
            grad[j] = np.angle(_model_h(p + dp, f) / _model_h(p - dp, f))[0] / 2e-6
        return float(np.degrees(np.sqrt(max(grad @ self.cov_log @ grad, 0.0))))

    def as_dict(self) -> dict:
        return {"rig": self.rig, "parameters": dict(self.params), "std": dict(self.std),
                "rms_phase_residual_deg": self.rms_phase_residual_deg,
                "rms_magnitude_residual_pct": self.rms_mag_residual_pct, "reduced_chi2": self.reduced_chi2,
                "phase_at_320Hz_deg": float(self.phase_deg(320.0)),
                "phase_at_320Hz_std_deg": self.phase_std_deg(320.0)}


def _residuals(p, f, h, w_mag, w_ph):
    m = _model_h(p, f)
    r = np.log(h / m)
    return np.concatenate([r.real / w_mag, _wrap(r.imag) / w_ph])


def fit_instrument(resp: FrequencyResponse) -> InstrumentFit:
    """Fit K, fn, zeta_n, f0, zeta_0 to a voice-coil response (see the module docstring)."""
    f, h = resp.frequency_hz, resp.h
    if f.size < 8:
        raise EstimationError(f"{resp.rig} sweep: {f.size} frequencies; the 5-parameter instrument fit needs >= 8")
    mag = np.abs(h)
    k0 = float(np.median(mag[: max(3, f.size // 10)]))
    peak = int(np.argmax(mag))
    if peak in (0, f.size - 1) or mag[peak] < 2 * k0:
        raise EstimationError(f"{resp.rig} sweep ({f[0]:.4g}-{f[-1]:.4g} Hz): no resonance peak inside the "
                              "sweep; the instrument fit needs frequencies beyond the load cell's resonance")
    w_mag = np.hypot(resp.ln_mag_se, MAG_FLOOR)
    w_ph = np.hypot(resp.phase_se_rad, PHASE_FLOOR_RAD)
    best = None
    for sf, zn, sf0, z0 in itertools.product((0.92, 1.0, 1.08), (0.01, 0.05), (0.5, 1.0, 2.0), (0.5, 1.0)):
        p0 = np.log([k0, sf * f[peak], zn, sf0 * f[-1], z0])
        sol = least_squares(_residuals, p0, args=(f, h, w_mag, w_ph), method="lm", max_nfev=2000)
        if best is None or sol.cost < best.cost:
            best = sol
    n, q = 2 * f.size, best.x.size
    chi2 = 2 * best.cost / max(n - q, 1)
    jtj = best.jac.T @ best.jac
    cov = np.linalg.pinv(jtj) * max(chi2, 1.0)
    vals = np.exp(best.x)
    params = dict(zip(PARAMS, map(float, vals)))
    std = dict(zip(PARAMS, map(float, vals * np.sqrt(np.diag(cov)))))
    r = np.log(h / _model_h(best.x, f))
    return InstrumentFit(resp.rig, params, std, float(np.degrees(np.sqrt(np.mean(_wrap(r.imag) ** 2)))),
                         float(100 * np.sqrt(np.mean(r.real ** 2))), float(chi2), resp, cov)


@dataclass(frozen=True)
class EddyLag:
    """Extra phase lag of a voice coil against a benchmark instrument model (Fig. 7c)."""

    rig: str
    reference: str
    frequency_hz: np.ndarray
    residual_deg: np.ndarray  # arg H - arg H_reference (negative: extra lag)
    tau_s: float
    tau_std_s: float
    lag_deg: float  # the fitted first-order lag at EDDY_CHECK_HZ
    lag_std_deg: float
    fitted_up_to_hz: float

    @property
    def significant(self) -> bool:
        return self.lag_deg > EDDY_MIN_DEG and self.lag_deg > 5 * self.lag_std_deg

    @property
    def verdict(self) -> str:
        if self.significant:
            return (f"eddy currents in the magnet: {self.lag_deg:.1f} +/- {self.lag_std_deg:.1f} deg extra lag at "
                    f"{EDDY_CHECK_HZ:g} Hz")
        return f"no significant extra lag ({self.lag_deg:.2f} +/- {self.lag_std_deg:.2f} deg at {EDDY_CHECK_HZ:g} Hz)"

    def as_dict(self) -> dict:
        return {"rig": self.rig, "reference": self.reference, "tau_s": self.tau_s, "tau_std_s": self.tau_std_s,
                "extra_lag_at_3kHz_deg": self.lag_deg, "extra_lag_at_3kHz_std_deg": self.lag_std_deg,
                "fitted_up_to_Hz": self.fitted_up_to_hz, "significant": self.significant,
                "verdict": self.verdict}


def eddy_lag(resp: FrequencyResponse, reference: InstrumentModel, reference_name: str) -> EddyLag:
    """Fit -atan(2 pi f tau) to the phase of ``resp`` beyond ``reference`` below 0.8 fn."""
    resid = _wrap(resp.phase_rad - np.radians(reference.phase_deg(resp.frequency_hz)))
    f_max = 0.8 * reference.fn_hz
    sel = resp.frequency_hz <= f_max
    if sel.sum() < 3:
        raise EstimationError(f"{resp.rig} sweep: fewer than 3 points below {f_max:.0f} Hz to fit an eddy lag")
    f, r = resp.frequency_hz[sel], resid[sel]
    w = np.hypot(resp.phase_se_rad[sel], PHASE_FLOOR_RAD)

    def res(p):
        return (r + np.arctan(2 * np.pi * f * p[0])) / w

    sol = least_squares(res, [1e-6], method="lm")
    chi2 = 2 * sol.cost / max(f.size - 1, 1)
    tau = float(sol.x[0])
    tau_se = float(np.sqrt(np.linalg.pinv(sol.jac.T @ sol.jac)[0, 0] * max(chi2, 1.0)))
    x = 2 * np.pi * EDDY_CHECK_HZ
    lag = float(np.degrees(np.arctan(x * tau)))
    lag_se = float(np.degrees(x * tau_se / (1 + (x * tau) ** 2)))
    return EddyLag(resp.rig, reference_name, resp.frequency_hz, np.degrees(resid), tau, tau_se, lag, lag_se, f_max)


def is_benchmark(rig: str) -> bool:
    """A voice coil whose magnet conducts too little for eddy currents (the paper's ferrite)."""
    vc = load_rig(rig).get("voicecoil", {})
    return vc.get("magnet") == "ferrite"


def read_sweeps(folder: str | Path) -> dict[str, list[Recording]]:
    """A sweep folder, or a folder of sweep folders: {name: recordings}, one rig each.

    A folder of one rig is one sweep named by the folder.  A bench day's folder holding several
    rigs (told apart by the sidecars' ``rig``) is one sweep per rig: named by the rig when it is
    the folder given, ``<folder>/<rig>`` when it is one of the folders under it."""
    folder = Path(folder)
    if not folder.is_dir():
        raise RecordingError(f"{folder}: not a folder")
    subs = sorted(p for p in folder.iterdir() if p.is_dir() and any(q.suffix == ".csv" for q in p.iterdir()))
    if any(p.suffix == ".csv" for p in folder.iterdir()):
        if subs:  # both: the sweeps under it were skipped without a word when it held one recording
            raise RecordingError(f"{folder}: holds recordings and sweep folders ({', '.join(p.name for p in subs[:4])}"
                                 f"{', ...' if len(subs) > 4 else ''}); give the sweep, or move its recordings into a "
                                 "folder of their own beside the others")
        return _by_rig(folder.name, read_sweep(folder), prefix=False)
    if not subs:
        raise RecordingError(f"{folder}: neither a sweep (NAME.csv + NAME.json) nor a folder of sweeps")
    return {name: recs for p in subs for name, recs in _by_rig(p.name, read_sweep(p), prefix=True).items()}


def _by_rig(name: str, recs: list[Recording], *, prefix: bool) -> dict[str, list[Recording]]:
    """``{name: recs}`` for one rig; else one entry per rig (``read_sweep`` keeps each rig's
    recordings together, in its order), keyed by the rig or, with ``prefix``, ``name/rig``."""
    recs = [with_flux(r) for r in recs]  # a sweep that recorded its sense coil's voltage
    rigs = dict.fromkeys(r.rig for r in recs)
    if len(rigs) == 1:
        return {name: recs}
    return {f"{name}/{rig}" if prefix else rig: [r for r in recs if r.rig == rig] for rig in rigs}


def preset_instrument(rig: str) -> InstrumentModel:
    """The rig preset's instrument model (the paper's values), the fallback benchmark."""
    return presets.instrument(load_rig(rig))
