"""The paper's measurement method on one recording: three delays from current, flux and force.

- hysteresis = flux behind current (the actuator's own lag: hysteresis and eddy currents);
- instrument = measured force behind the flux (with magnet, the force follows the flux) or behind
  the flux squared (without magnet the force is quadratic: its 2f component);
- total = measured force behind current (behind current squared without magnet).

The flux is seen by no force instrument, which is what separates the two lags (paper Sec. III).
Each delay is the equivalent time delay of the signal's dominant component (f with magnet, 2f
without) and, for display, the phase that delay is at the excitation frequency.

The delays come from least-squares sine fits (at the Cramer-Rao bound), each channel fitted once:
current and flux jointly with the frequency, the force (and without magnet i^2 and phi^2) at that
frequency; every delay is read off those fits, so all three are at one frequency and, with magnet,
total = hysteresis + instrument to rounding.  The paper's own covariance-maximum delays (Eq. 3,
one-sample resolution) are given beside them by :func:`covariance_delays`.  Before any number is
returned the recording is checked: an E-core rig, the three channels present, finite, not flat,
not clipped, at least two periods long, and the nominal frequency really in the data (the fitted
frequency near the sidecar's; each channel's fitted component carrying at least half its variance,
or its spectrum peaking there, and never less than ``MIN_EXPLAINED_ANYWAY``).  Anything else is an
:class:`EstimationError` naming the recording and the reason.

Gross outliers (a glitch: a sample ``OUTLIER_SIGMAS`` robust standard deviations off its channel's
fitted waveform) are found per channel, reported by sample index (``outliers``) and left out of
every fit and check (``outliers_excluded``); a channel with more than ``MAX_OUTLIER_FRACTION`` of
them is refused: that is a broken channel, not a glitch.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Mapping

import numpy as np

from ..config import load_rig
from ..errors import EstimationError
from ..physics import presets
from .estimation import (OUTLIER_SIGMAS, PhaseDelay, covariance_delay, delay_between, estimation_errors, gross_outliers,
                         phase_delay, sine_fit)
from .estimation import find_outliers as estimation_find_outliers
from ..formats.recording import Recording
from .sense_coil import OUTLIERS, with_flux

__all__ = ["MethodDelays", "measure_delays", "measure_window", "has_magnet", "covariance_delays", "estimate",
           "recording_name", "check_channels", "check_fit_quality", "find_outliers", "outlier_summary",
           "MAX_FREQUENCY_OFFSET", "MIN_EXPLAINED", "MIN_EXPLAINED_ANYWAY", "MAX_OUTLIER_FRACTION"]

DELAY_NAMES = ("hysteresis", "instrument", "total")
#: Largest relative distance of the fitted from the nominal frequency (generator and ADC clocks
#: differ by tens of ppm; 1000 ppm means the sidecar names another frequency than the data's).
MAX_FREQUENCY_OFFSET = 1e-3
#: Smallest share of a channel's variance its fitted component must carry, unless the channel's
#: spectrum peaks there anyway (a weak but clean signal); a channel at another frequency, or pure
#: noise, fails both.
MIN_EXPLAINED = 0.5
#: ... and below this share a channel is refused even if its spectrum peaks at the frequency
#: (its noise or junk is 19 times the component's power: no phase worth reporting).
MIN_EXPLAINED_ANYWAY = 0.05
#: A channel with more outliers than this share of its samples is refused (a broken channel).
MAX_OUTLIER_FRACTION = 0.01
#: A channel is called clipped when more of its samples sit at its extreme value than this, and
#: more than a quantised sine of its amplitude would have there (see :func:`_unclipped_share`).
MAX_PINNED_FRACTION = 0.02
#: Harmonics fitted in every channel: the delay is read at one of them, the others keep the force's
#: k2 i^2 term and the iron's distortion from leaking into it (records are not whole periods).
HARMONICS = (1, 2, 3, 4)


@dataclass(frozen=True)
class MethodDelays:
    """The method's result for one recording (delays and their standard errors, with what was
    left out), in one type for identification, force error and the reports."""

    frequency_hz: float  # estimated true excitation frequency
    frequency_std_hz: float
    harmonic: int  # 1 with magnet, 2 without (the force's dominant component)
    delays_s: dict[str, float]
    delays_std_s: dict[str, float]
    nominal_frequency_hz: float = math.nan
    current_pp_a: float = math.nan  # nominal (sidecar)
    recording: str = ""
    explained: dict[str, float] = field(default_factory=dict)  # variance share of each channel's fit
    outliers: dict[str, list[int]] = field(default_factory=dict)  # channel -> sample indices left out

    def phase_deg(self, name: str) -> float:
        """The delay as a phase at the excitation frequency, degrees (positive: lag)."""
        return 360.0 * self.frequency_hz * self.delays_s[name]

    def phase_std_deg(self, name: str) -> float:
        return 360.0 * self.frequency_hz * self.delays_std_s[name]

    @property
    def theta_hyst_rad(self) -> float:
        """The paper's theta_hyst: the flux's phase lag behind the current at f (rad)."""
        return 2 * np.pi * self.frequency_hz * self.delays_s["hysteresis"]

    def as_dict(self) -> dict:
        return {
            "frequency_Hz": self.frequency_hz,
            "frequency_std_Hz": self.frequency_std_hz,
            "harmonic": self.harmonic,
            "delays_s": dict(self.delays_s),
            "delays_std_s": dict(self.delays_std_s),
            "phases_deg": {k: self.phase_deg(k) for k in self.delays_s},
            "phases_std_deg": {k: self.phase_std_deg(k) for k in self.delays_s},
            "outliers": {k: list(v) for k, v in self.outliers.items()},
            "outliers_excluded": any(self.outliers.values()),
        }


def recording_name(rec: Recording) -> str:
    """What a message calls the recording: its path, or its rig and operating point."""
    if rec.path is not None:
        return str(rec.path)
    return f"{rec.rig} recording at {rec.frequency_hz:g} Hz, {rec.current_pp_a:g} A-pp"


def has_magnet(rec: Recording) -> bool:
    """Whether the recording's rig has a pre-biasing magnet (so force is affine in flux)."""
    return "magnet" in load_rig(rec.rig)


def _pinned_fraction(x: np.ndarray, lo: float, hi: float) -> tuple[float, float]:
    """(share of samples at the max ``hi`` or the min ``lo``, that value)."""
    tol = 1e-12 * max(abs(lo), abs(hi), hi - lo)
    at_hi, at_lo = np.count_nonzero(x >= hi - tol) / x.size, np.count_nonzero(x <= lo + tol) / x.size
    return (at_hi, hi) if at_hi >= at_lo else (at_lo, lo)


def _unclipped_share(x: np.ndarray) -> float:
    """The share of samples a quantised sine of ``x``'s amplitude leaves on its extreme code.

    A sine of amplitude A quantised with step q stays there for about sqrt(2 q / A) / pi of the
    samples; clipping pins many more.  Three times that is allowed; q is the smallest step between
    distinct values (float data: effectively 0).  A sort of the record: asked only when more than
    MAX_PINNED_FRACTION sit at an extreme (the live stage checks every channel of every window)."""
    u = np.unique(x)
    q = float(np.min(np.diff(u))) if u.size > 1 else 0.0
    return 3.0 * math.sqrt(2 * q / max(float(np.ptp(x)) / 2, 1e-300)) / math.pi


def _in_flat_tops(x: np.ndarray, value: float) -> float:
    """The share of samples at ``value`` on a flat top: in runs of three or more, or in pairs whose
    outer neighbours differ.  A sine sampled in step with its period (an integer number of samples
    per period: a clock locked to the generator) meets its extreme at the same sample every period:
    one sample, or two straddling the peak with equal neighbours, never three; 5 % of a record at
    20 samples per period sat at its minimum and was called clipped."""
    tol = 1e-12 * max(abs(value), 1e-300)
    at = np.abs(x - value) <= tol
    member = np.zeros(x.size, bool)
    triple = at[:-2] & at[1:-1] & at[2:]
    for k in range(3):
        member[k:k + triple.size] |= triple
    if x.size >= 4:  # a pair x[i], x[i+1] alone at the extreme, its neighbours x[i-1] and x[i+2]
        i = np.arange(1, x.size - 2)
        alone = at[i] & at[i + 1] & ~at[i - 1] & ~at[i + 2]
        lopsided = np.abs(x[i - 1] - x[i + 2]) > 1e-9 * max(float(np.ptp(x)), 1e-300)
        pair = i[alone & lopsided]
        member[pair] = member[pair + 1] = True
    return float(np.count_nonzero(member)) / x.size


def _check_clipping(where: str, name: str, x: np.ndarray, lo: float, hi: float) -> None:
    """Refuse a channel ``x`` (its min ``lo``, max ``hi``) that looks clipped."""
    frac, value = _pinned_fraction(x, lo, hi)
    if frac <= MAX_PINNED_FRACTION:
        return
    frac = _in_flat_tops(x, value)
    if frac <= MAX_PINNED_FRACTION:
        return
    expected = _unclipped_share(x)
    if frac > max(MAX_PINNED_FRACTION, expected):
        raise EstimationError(f"{where}: channel {name!r} looks clipped: {100 * frac:.1f} % of its samples "
                              f"sit at {value:.6g} (a sine of its amplitude would have < "
                              f"{100 * max(MAX_PINNED_FRACTION, expected):.1f} %)")


#: The largest a channel may reach apart from its outliers: far beyond any current, flux, force or
#: voltage, and small enough that the fits' squares stay finite (a channel at 1e157 overflowed them;
#: one glitch of 1e308 is an outlier, found and left out).
MAX_CHANNEL_MAGNITUDE = 1e30
#: The smallest swing a channel may have: below any quantity of a bench in SI units, and large enough
#: that the fits' squares stay normal numbers (a channel scaled to 1e-200 ended in "Singular matrix").
MIN_CHANNEL_SWING = 1e-30


def check_channels(rec: Recording, names: tuple[str, ...]) -> dict[str, np.ndarray]:
    """The named channels, each checked present, finite, varying and not clipped (judged without
    its gross outliers: one 1e308 sample would make every other one sit at the minimum), and the
    record at least two periods of the nominal frequency long."""
    where = recording_name(rec)
    if rec.metadata.get("clipped") is True:
        raise EstimationError(f"{where}: the sidecar says 'clipped': true (a sample reached an ADC or "
                              "amplifier limit); the phases of a clipped recording are not trusted")
    out = {}
    for name in names:
        if name not in rec.channels:
            also = " (or sense_V, with the sidecar's sense_turns)" if name == "flux_Wb" else ""
            raise EstimationError(f"{where}: the method needs a {name!r} column{also}; it has {sorted(rec.channels)}")
        x = np.asarray(rec.channels[name], dtype=float)
        if x.size == 0:
            raise EstimationError(f"{where}: channel {name!r} has no samples")
        lo, hi = float(x.min()), float(x.max())  # the live stage checks every window: each pass counts
        if not (math.isfinite(lo) and math.isfinite(hi)):  # a NaN or an infinity shows in one of them
            bad = ~np.isfinite(x)
            raise EstimationError(f"{where}: channel {name!r} has {int(bad.sum())} NaN or infinite "
                                  f"sample(s), the first at sample {int(np.argmax(bad))}")
        if hi - lo == 0.0:
            raise EstimationError(f"{where}: channel {name!r} is flat (every sample {float(x[0])!r}): it carries no phase")
        gross = gross_outliers(x)
        kept = x
        if gross.any():
            kept = x[~gross]
            lo, hi = float(kept.min()), float(kept.max())
            if hi - lo == 0.0:
                raise EstimationError(f"{where}: channel {name!r} is flat apart from {int(gross.sum())} outlier "
                                      f"sample(s) (first at {int(np.argmax(gross))}): it carries no phase")
        if max(abs(lo), abs(hi)) > MAX_CHANNEL_MAGNITUDE:  # a whole channel this large overflowed the fits
            raise EstimationError(f"{where}: channel {name!r} reaches {max(abs(lo), abs(hi)):.3g} apart from its "
                                  f"outliers: beyond {MAX_CHANNEL_MAGNITUDE:g}, no quantity of a bench (a unit or a scale?)")
        if hi - lo < MIN_CHANNEL_SWING:
            raise EstimationError(f"{where}: channel {name!r} swings by {hi - lo:.3g} apart from its outliers: below "
                                  f"{MIN_CHANNEL_SWING:g}, no quantity of a bench (a unit or a scale?)")
        _check_clipping(where, name, kept, lo, hi)
        out[name] = x
    f = rec.frequency_hz
    periods = rec.n * f / rec.fs_hz
    if periods < 2.0:
        raise EstimationError(f"{where}: {rec.n} samples at {rec.fs_hz:g} Hz cover {periods:.2f} periods of "
                              f"{f:g} Hz; the method needs at least two")
    return out


def _fft_peak_hz(x: np.ndarray, fs_hz: float) -> float:
    spec = np.abs(np.fft.rfft(x - x.mean()))
    spec[0] = 0.0
    return float(np.argmax(spec) * fs_hz / x.size)


def _explained(fit, k: int, x: np.ndarray) -> float:
    """Share of a channel's variance (its samples the fit kept) carried by its fitted harmonic ``k``."""
    kept = x[~fit.excluded] if fit.excluded.any() else x
    return 0.5 * float(fit.component(k).amplitude) ** 2 / max(float(np.var(kept)), 1e-300)


def _filled(x: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """``x`` with the masked samples interpolated from their neighbours (for what needs uniform
    samples: a spectrum, the covariance method)."""
    if not mask.any():
        return x
    out = x.copy()
    kept = np.flatnonzero(~mask)
    out[mask] = np.interp(np.flatnonzero(mask), kept, x[kept])
    return out


def _index_mask(n: int, indices: list[int]) -> np.ndarray:
    """A boolean mask of ``n`` samples, True at ``indices``."""
    mask = np.zeros(n, dtype=bool)
    mask[indices] = True
    return mask


def check_fit_quality(rec: Recording, f_fit: float, fits: dict[str, tuple[object, int]]) -> dict[str, float]:
    """Refuse fits that did not find the nominal frequency: ``fits`` maps a channel to its
    (SineFit, harmonic); returns the share of each channel's variance its fit explains (over the
    samples the fit kept)."""
    where = recording_name(rec)
    f_nom = rec.frequency_hz
    shares = {}
    for name, (fit, k) in fits.items():
        share = _explained(fit, k, rec.channels[name])
        shares[name] = share
        what = f"{f_nom:g} Hz" if k == 1 else f"{k} x {f_nom:g} Hz"
        peak = k * f_fit
        if share < MIN_EXPLAINED:
            peak = _fft_peak_hz(_filled(np.asarray(rec.channels[name], dtype=float), fit.excluded), rec.fs_hz)
        bin_hz = rec.fs_hz / rec.n
        if share < MIN_EXPLAINED and abs(peak - k * f_fit) > max(2 * bin_hz, 0.005 * k * f_fit):
            raise EstimationError(
                f"{where}: channel {name!r} has no clear component at {what}: the fitted sine explains "
                f"{100 * share:.1f} % of its variance and its spectrum peaks at {peak:.6g} Hz. Is "
                f"frequency_Hz = {f_nom:g} in the sidecar right?")
        if share < MIN_EXPLAINED_ANYWAY:
            raise EstimationError(
                f"{where}: channel {name!r}: the fitted component at {what} explains only {100 * share:.2g} % of "
                f"its variance (at least {100 * MIN_EXPLAINED_ANYWAY:g} % needed): the channel is mostly noise "
                "or something else than the excitation")
    if abs(f_fit / f_nom - 1.0) > MAX_FREQUENCY_OFFSET:
        raise EstimationError(f"{where}: the data's frequency {f_fit:.6g} Hz is {1e6 * (f_fit / f_nom - 1):+.0f} ppm "
                              f"from the sidecar's frequency_Hz {f_nom:g} (allowed "
                              f"{1e6 * MAX_FREQUENCY_OFFSET:.0f} ppm)")
    return shares


def _require_ecore(rec: Recording) -> bool:
    """True if the rig has a magnet; an error for rigs that are not E-cores."""
    preset = load_rig(rec.rig)
    kind = preset.get("actuator")
    if kind != "ecore":
        hint = " (use `hystbench identify` on a voice-coil sweep)" if kind == "voicecoil" else ""
        raise EstimationError(f"{recording_name(rec)}: rig {rec.rig!r} is a {kind}, not an E-core: the "
                              f"flux/force method needs an E-core recording{hint}")
    return "magnet" in preset


def _drives(current: np.ndarray, flux: np.ndarray, magnet: bool) -> tuple[np.ndarray, np.ndarray]:
    """The references the force is compared with: i and phi with magnet, i^2 and phi^2 without."""
    if magnet:
        return current, flux
    return (current - current.mean()) ** 2, (flux - flux.mean()) ** 2


def _drive_fits(current: np.ndarray, flux: np.ndarray, m_i: np.ndarray, m_phi: np.ndarray, fs_hz: float,
                f_true: float) -> PhaseDelay:
    """Without magnet the force follows i^2 and phi^2 (its 2f component): their fits at the
    frequency found (``.x``: i^2, ``.y``: phi^2), the outliers found in i and phi left out."""
    drive_i, drive_phi = _drives(_filled(current, m_i), _filled(flux, m_phi), magnet=False)
    return phase_delay(drive_i, drive_phi, fs_hz, f_true, harmonic=2, harmonics=HARMONICS, fit_freq=False,
                       exclude=(m_i, m_phi), outlier_sigmas=None)


def find_outliers(rec: Recording, names: tuple[str, ...], *, sigmas: float = OUTLIER_SIGMAS) -> dict[str, np.ndarray]:
    """Each named channel's gross outliers (a boolean mask per channel): samples more than
    ``sigmas`` robust standard deviations off the channel's fitted waveform (DC and
    :data:`HARMONICS` of the excitation, one frequency for all, from one joint fit); a channel
    with more than ``MAX_OUTLIER_FRACTION`` of them is refused."""
    where = recording_name(rec)
    with estimation_errors(where):
        masks, _ = estimation_find_outliers([rec.channels[c] for c in names], rec.fs_hz, rec.frequency_hz,
                                            harmonics=HARMONICS, names=[f"channel {c!r}" for c in names],
                                            outlier_sigmas=sigmas)
    out = dict(zip(names, masks))
    _check_outlier_share(rec, out, sigmas)
    return out


def outlier_summary(outliers: dict[str, list[int]], first: int = 5) -> str:
    """One line naming each channel's outlier samples: ``force_N at 4321, 7000 (2)``."""
    return "; ".join(f"{c} at {', '.join(map(str, v[:first]))}{', ...' if len(v) > first else ''} ({len(v)})"
                     for c, v in outliers.items() if v)


def _check_outlier_share(rec: Recording, masks: dict[str, np.ndarray], sigmas: float = OUTLIER_SIGMAS) -> None:
    """More than ``MAX_OUTLIER_FRACTION`` outliers: a broken channel, not a glitch."""
    where = recording_name(rec)
    for name, mask in masks.items():
        n_out = int(mask.sum())
        if n_out > MAX_OUTLIER_FRACTION * rec.n:
            raise EstimationError(f"{where}: channel {name!r} has {n_out} samples more than {sigmas:g} robust standard "
                                  f"deviations off its fitted waveform ({100 * n_out / rec.n:.2g} %, at most "
                                  f"{100 * MAX_OUTLIER_FRACTION:g} % are left out as outliers): first at "
                                  f"{', '.join(map(str, np.flatnonzero(mask)[:5]))}; is the channel broken?")


def measure_delays(rec: Recording) -> MethodDelays:
    """Hysteresis, instrument and total delay of one recording (paper Secs. III, V, VI), with
    each channel's gross outliers left out (and named in the result): the current's and the
    flux's found by their joint fit, the force's by its own fit at the frequency found.  A recording
    of the sense coil's voltage is integrated first (:func:`~.sense_coil.with_flux`)."""
    rec = with_flux(rec)
    return _measure(rec, _require_ecore(rec))


@dataclass(frozen=True)
class _Window:
    """What the method reads of a recording, for bare samples (the live estimator's windows)."""

    path: str
    channels: Mapping[str, np.ndarray]
    fs_hz: float
    frequency_hz: float
    current_pp_a: float
    metadata: Mapping[str, Any] = field(default_factory=dict)

    @property
    def n(self) -> int:
        return len(next(iter(self.channels.values())))


def measure_window(channels: Mapping[str, np.ndarray], fs_hz: float, frequency_hz: float, *, magnet: bool,
                   current_pp_a: float = math.nan, where: str = "window") -> MethodDelays:
    """:func:`measure_delays` on bare samples of an E-core rig (``magnet``: whether it has one),
    named ``where`` in errors: the live estimator knows its rig once per run, so no sidecar is
    checked and no rig preset read for each window."""
    return _measure(_Window(where, channels, float(fs_hz), float(frequency_hz), float(current_pp_a)), magnet)


def _measure(rec: Recording | _Window, magnet: bool) -> MethodDelays:
    where = recording_name(rec)
    names = ("current_A", "flux_Wb", "force_N")
    ch = check_channels(rec, names)
    current, flux, force = ch["current_A"], ch["flux_Wb"], ch["force_N"]
    k = 1 if magnet else 2
    fs, f0 = rec.fs_hz, rec.frequency_hz
    with estimation_errors(where):
        hyst = phase_delay(current, flux, fs, f0, harmonic=1, harmonics=HARMONICS)
        f_true = float(hyst.frequency_hz)
        force_fit = sine_fit(force, fs, f_true, harmonics=HARMONICS, fit_freq=False)
    m_i, m_phi, m_f = hyst.x.excluded, hyst.y.excluded, force_fit.excluded
    masks = {"current_A": m_i, "flux_Wb": m_phi, "force_N": m_f}
    _check_outlier_share(rec, masks)
    with estimation_errors(where):
        refs = hyst if magnet else _drive_fits(current, flux, m_i, m_phi, fs, f_true)
        instr = delay_between(refs.y, force_fit, k)  # every channel fitted once, at one frequency
        total = delay_between(refs.x, force_fit, k)
    explained = check_fit_quality(rec, f_true, {"current_A": (hyst.x, 1), "flux_Wb": (hyst.y, 1),
                                                "force_N": (force_fit, k)})
    delays = {"hysteresis": float(hyst.delay_s), "instrument": float(instr.delay_s), "total": float(total.delay_s)}
    stds = {"hysteresis": float(hyst.delay_se_s), "instrument": float(instr.delay_se_s),
            "total": float(total.delay_se_s)}
    outliers = {c: np.flatnonzero(m).tolist() for c, m in masks.items() if m.any()}
    return MethodDelays(f_true, float(hyst.frequency_se_hz), k, delays, stds, f0, rec.current_pp_a, where, explained,
                        outliers)


def covariance_delays(rec: Recording, frequency_hz: float | None = None,
                      outliers: dict[str, np.ndarray] | None = None) -> dict[str, float]:
    """The paper's Eq. 3 delays (s): the lag of the covariance maximum, one-sample resolution.

    Same pairs as :func:`measure_delays`; the search spans one period of the compared signals
    (of f with magnet, of 2f without), at ``frequency_hz`` (default: the nominal frequency).
    Outlier samples (``outliers``, masks by channel; default: found as the fits find them) are
    interpolated from their neighbours, as the method needs every sample."""
    where = recording_name(rec)
    magnet = _require_ecore(rec)
    names = ("current_A", "flux_Wb", "force_N")
    ch = check_channels(rec, names)
    masks = find_outliers(rec, names) if outliers is None else outliers
    ch = {c: _filled(x, masks[c]) if c in masks else x for c, x in ch.items()}
    f = rec.frequency_hz if frequency_hz is None else float(frequency_hz)
    k = 1 if magnet else 2
    drive_i, drive_phi = _drives(ch["current_A"], ch["flux_Wb"], magnet)
    with estimation_errors(where):
        hyst = covariance_delay(ch["current_A"], ch["flux_Wb"], rec.fs_hz, f)
        instr = covariance_delay(drive_phi, ch["force_N"], rec.fs_hz, k * f)
        total = covariance_delay(drive_i, ch["force_N"], rec.fs_hz, k * f)
    return {"hysteresis": float(hyst.delay_s), "instrument": float(instr.delay_s), "total": float(total.delay_s)}


def estimate(rec: Recording) -> dict:
    """Everything ``hystbench estimate`` reports on one recording, as plain JSON-ready data.

    Delays in s (positive: the later-named signal lags), phases in degrees at the excitation
    frequency; the covariance method's delays (paper Eq. 3) beside the sine-fit ones; and the rig
    preset's instrument model (paper Figs. 8-9) at the force's frequency for comparison.  The sense
    voltage's samples bridged as outliers before it was integrated are among ``outliers``."""
    rec = with_flux(rec)
    d = measure_delays(rec)
    masks = {c: _index_mask(rec.n, v) for c, v in d.outliers.items()}
    cov = covariance_delays(rec, d.frequency_hz, masks)
    f = d.frequency_hz
    model = presets.instrument(load_rig(rec.rig))
    model_delay = float(model.delay_s(d.harmonic * f))
    found = d.as_dict()
    if rec.metadata.get(OUTLIERS):  # bridged in the voltage before it was integrated
        found["outliers"]["sense_V"] = list(rec.metadata[OUTLIERS])
        found["outliers_excluded"] = True
    return {
        "recording": d.recording,
        "rig": rec.rig,
        "nominal_frequency_Hz": rec.frequency_hz,
        "current_pp_A": rec.current_pp_a,
        "sample_rate_Hz": rec.fs_hz,
        "samples": rec.n,
        **found,
        "theta_hyst_deg": d.phase_deg("hysteresis"),
        "explained_variance": d.explained,
        "covariance_method": {
            "delays_s": cov,
            "phases_deg": {k: 360.0 * f * v for k, v in cov.items()},
            "resolution_s": 1.0 / rec.fs_hz,
        },
        "instrument_model": {"delay_s": model_delay, "phase_deg": 360.0 * f * model_delay,
                             "at_Hz": d.harmonic * f, "source": str(load_rig(rec.rig)["_source"])},
    }
