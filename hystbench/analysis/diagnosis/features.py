"""What a recording says, as numbers with standard errors: the features the diagnosis compares.

A diagnosis compares a recording with its simulation channel by channel, harmonic by harmonic, so
both are reduced here to the same few numbers, each with the standard error that makes a
difference a z-score:

- ``harmonics``: the period average's Fourier coefficients, ``x(t) ~= X_0 + sum_k Re(X_k e^{ikwt})``
  (``|X_k|`` the amplitude, ``X_0`` the mean), every channel shifted by the same time so that the
  current's fundamental is real and positive: features then do not depend on where a record starts.
- ``dc_slope``: the drift of the per-period mean within the record (charge amplifiers, heating).
- ``lines``: sines that are not harmonics (mains pick-up): a 50 Hz line averages out over the
  periods of most frequencies, so it is fitted on the raw record minus the periodic extension of
  its average.
- ``noise_rms``: the sensor noise per sample.

The periodic part, the drift and the lines are estimated jointly (the residual after the average is
linear in the drift and in the lines, leaks included), so a drift or a mains line does not bias
the harmonics.  Harmonics reach the Cramer-Rao bound for white noise: the average is resampled on
at least 1.25 points per sample (fewer would alias resampled noise into every harmonic) and the
cubic spline's gain is divided out.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np
from scipy.stats import chi2

from ...formats.recording import Recording
from ..method import recording_name
from ..periodic import estimate_frequency, period_average

__all__ = ["RecordFeatures", "record_features", "spline_gain", "CURRENT", "NYQUIST_SHARE"]

CURRENT = "current_A"
#: Harmonics at or above this share of the sample rate are not reported (NaN): the spline and
#: the instruments' anti-alias filters leave them unreliable.
NYQUIST_SHARE = 0.45
#: The coloured-noise check inflates the SE only when the noise density near a harmonic exceeds
#: white noise at this significance (white noise alone exceeds its SE half of the time).
COLOURED_P = 0.01
_OVERSAMPLE = 4  # the average's grid is refined this much before linear interpolation at samples


@dataclass(frozen=True)
class RecordFeatures:
    """One recording's features (see the module docstring); arrays indexed by harmonic k = 0..K."""

    name: str
    rig: str
    frequency_hz: float
    current_pp_a: float
    start_time_s: float | None
    duration_s: float
    fs_hz: float
    periods: int
    harmonics: dict[str, np.ndarray]
    se: dict[str, np.ndarray]
    dc_slope: dict[str, tuple[float, float]]
    lines: dict[str, dict[float, tuple[complex, float]]]
    noise_rms: dict[str, float]


def spline_gain(omega: np.ndarray) -> np.ndarray:
    """Gain of cardinal cubic-spline interpolation at ``omega`` rad/sample: sinc^4 of the cubic
    B-spline over its sampled kernel (2 + cos w) / 3; the period average resamples through it."""
    w = np.asarray(omega, float)
    return np.sinc(w / (2 * np.pi)) ** 4 * 3.0 / (2.0 + np.cos(w))


def _start_time(rec: Recording) -> float | None:
    value = getattr(rec, "start_time_s", None)
    if value is None:
        value = rec.metadata.get("start_time_s")
    return None if value is None else float(value)


def record_features(rec: Recording, harmonics: int = 7, lines_hz: Sequence[float] = (50.0, 150.0, 60.0, 180.0),
                    n_points: int = 256, frequency_hz: float | None = None) -> RecordFeatures:
    """The features of ``rec`` up to harmonic ``harmonics``, with the non-harmonic ``lines_hz``.

    ``n_points`` is the least number of phases of the period average (more are taken when a period
    holds more samples); ``frequency_hz`` the true frequency when it is known (a simulation's),
    else it is estimated from the current.  ``ValueError`` naming the recording for one without ``current_A``, with
    fewer than two whole periods or whose current has no fundamental to reference phases to."""
    name = recording_name(rec)
    if CURRENT not in rec.channels:
        raise ValueError(f"{name}: no {CURRENT} channel; features are referenced to the current "
                         f"(channels: {', '.join(rec.channels)})")
    K, fs_hz, n = int(harmonics), rec.fs_hz, rec.n
    if K < 1:
        raise ValueError(f"harmonics must be >= 1, got {harmonics!r}")
    try:
        f = (float(frequency_hz) if frequency_hz
             else estimate_frequency(rec.channels[CURRENT], fs_hz, rec.frequency_hz))
    except ValueError as err:  # the estimator names its argument (x): say which column that is
        raise ValueError(f"{name}: column {CURRENT}, from which the frequency is estimated: {err}") from err
    if f >= NYQUIST_SHARE * fs_hz:
        raise ValueError(f"{name}: the fundamental {f:g} Hz is above {NYQUIST_SHARE} of the sample rate "
                         f"{fs_hz:g} Hz")
    spp = fs_hz / f  # samples per period
    n_grid = max(int(n_points), 2 * K + 2, int(math.ceil(1.25 * spp)))
    names = tuple(rec.channels)
    try:
        pa = period_average(rec.channels, fs_hz, f, n_grid, names=names)
    except ValueError as err:
        raise ValueError(f"{name}: {err}") from err
    P = pa.periods
    if P < 2:
        raise ValueError(f"{name}: {rec.duration_s:g} s hold {P} whole period of {f:g} Hz; features need two")
    X = np.stack([pa.channels[c] for c in names])  # (C, n_grid)
    t = np.arange(n) / fs_hz
    cycles = t * f
    phase = cycles - np.floor(cycles)
    n_whole = min(n, int(math.floor(P * spp)) + 1)
    freqs = np.fft.rfftfreq(n_grid, 1.0 / n_grid) * f  # harmonic k at k f Hz
    gain = np.where(freqs < 0.5 * fs_hz, spline_gain(2 * np.pi * freqs / fs_hz), np.inf)

    def extend(grid: np.ndarray) -> np.ndarray:
        """Periodic extension of grid values (rows) at every sample's phase, band-limited like the
        average itself (same spline-gain correction), so a column built with it matches ext(avg)."""
        spec = np.fft.rfft(grid, axis=-1) / gain
        fine = np.fft.irfft(spec, n=_OVERSAMPLE * n_grid, axis=-1) * _OVERSAMPLE
        fine = np.concatenate([fine, fine[..., :1]], axis=-1)
        where = phase * (_OVERSAMPLE * n_grid)
        i0 = np.minimum(where.astype(np.int64), _OVERSAMPLE * n_grid - 1)
        frac = where - i0
        return fine[..., i0] * (1 - frac) + fine[..., i0 + 1] * frac

    # Columns of the residual model: a drift (staircase left after the average took its ramp) and
    # each line (minus what leaked of it into the average).
    grid_phase = pa.phase
    ramp_grid = (grid_phase - 0.5) / f
    kept = [float(h) for h in lines_hz if _separable(float(h), f, fs_hz, n / fs_hz)]
    omegas = 2 * np.pi * np.asarray(kept)
    p_idx = np.arange(P)
    leak = np.exp(1j * np.outer(omegas, p_idx / f)).mean(axis=1)  # D_l: a line's share in the average
    line_grid = leak[:, None] * np.exp(1j * np.outer(omegas, grid_phase / f))  # (L, n_grid) complex
    model_grid = np.concatenate([ramp_grid[None], line_grid.real, line_grid.imag])  # Re(L e) = Lr cos - Li sin
    raw_cols = np.concatenate([(t - P / (2 * f))[None], np.cos(np.outer(omegas, t)), np.sin(np.outer(omegas, t))])
    extended = extend(np.concatenate([model_grid, X]))  # one pass for the model's columns and the channels
    A = (raw_cols - extended[:len(model_grid)]).T  # (n, 1 + 2L)
    data = np.stack([rec.channels[c] for c in names])
    resid = data - extended[len(model_grid):]  # (C, n)
    cov_unit = np.linalg.pinv(A.T @ A)  # normal equations: A has 1 + 2L well-separated columns
    coef = cov_unit @ (A.T @ resid.T)  # (1 + 2L, C)
    left = resid - (A @ coef).T
    sigma = np.sqrt(np.mean(left[:, :n_whole] ** 2, axis=1) * P / (P - 1))
    slope = coef[0]
    L = len(kept)
    line_amp = coef[1:1 + L] - 1j * coef[1 + L:]  # Re(L e^{iwt}) = Re(L) cos - Im(L) sin -> coef_sin = -Im
    line_se_unit = np.sqrt(0.5 * (np.diag(cov_unit)[1:1 + L] + np.diag(cov_unit)[1 + L:]))

    # The periodic part alone: the average minus its drift ramp and the lines' leaks.
    clean = X - slope[:, None] * ramp_grid[None] - (line_amp.T @ line_grid).real
    valid = freqs[:K + 1] < NYQUIST_SHARE * fs_hz
    scale = np.r_[1.0, np.full(K, 2.0)] / n_grid
    spec = np.fft.rfft(clean, axis=-1)[:, :K + 1] * scale / gain[:K + 1]
    N = P * spp
    se_white = sigma[:, None] * np.r_[1.0 / math.sqrt(N), np.full(K, math.sqrt(2.0 / N))][None]
    ratio = _coloured_ratio(left, sigma, f, fs_hz, K)
    se = se_white * ratio

    ci = names.index(CURRENT)
    i1 = spec[ci, 1]
    if not np.isfinite(i1) or abs(i1) <= 3 * se[ci, 1]:
        raise ValueError(f"{name}: the current's fundamental at {f:g} Hz ({abs(i1):.3g} A) is lost in its noise; "
                         "phases have no reference (is the sidecar's frequency_Hz the excitation's?)")
    turn = np.exp(-1j * np.arange(K + 1) * np.angle(i1))
    spec = spec * turn[None]
    # The reference's own noise turns every channel: k |X_k| sigma_theta, shared by Re and Im.
    sigma_theta = se[ci, 1] / abs(i1)
    se = np.sqrt(se ** 2 + 0.5 * (np.arange(K + 1)[None] * np.abs(spec) * sigma_theta) ** 2)
    se[ci, 1] = se_white[ci, 1] * ratio[ci, 1]
    spec[:, ~valid] = np.nan
    se[:, ~valid] = np.nan

    dc = _dc_slopes(data, fs_hz, spp, P, line_amp, omegas, f)
    return RecordFeatures(
        name=name, rig=rec.rig, frequency_hz=float(f), current_pp_a=rec.current_pp_a, start_time_s=_start_time(rec),
        duration_s=rec.duration_s, fs_hz=fs_hz, periods=P,
        harmonics={c: spec[i].copy() for i, c in enumerate(names)},
        se={c: se[i].copy() for i, c in enumerate(names)},
        dc_slope={c: dc[i] for i, c in enumerate(names)},
        lines={c: {h: (complex(line_amp[j, i]), float(sigma[i] * line_se_unit[j])) for j, h in enumerate(kept)}
               for i, c in enumerate(names)},
        noise_rms={c: float(sigma[i]) for i, c in enumerate(names)})


def _separable(line_hz: float, f: float, fs_hz: float, duration_s: float) -> bool:
    """A line can be told from the periodic part only 2/duration away from every harmonic k f
    (any k: every harmonic is in the average), and below NYQUIST_SHARE of fs."""
    if not (math.isfinite(line_hz) and 0 < line_hz < NYQUIST_SHARE * fs_hz):
        return False
    return abs(line_hz - round(line_hz / f) * f) >= 2.0 / duration_s


def _coloured_ratio(left: np.ndarray, sigma: np.ndarray, f: float, fs_hz: float, K: int) -> np.ndarray:
    """(C, K+1): how far the noise density near each harmonic exceeds white noise of the same rms.

    Drift, mains and 1/f noise are coloured: dense near the low harmonics, thin elsewhere, so the
    per-sample rms understates the error of a harmonic.  The residual (record minus periodic part,
    drift and lines) is noise only; its periodogram between 2/duration and f/2 away from k f (the
    bins the period average did not notch; at two periods the half-harmonics, which is what the
    alternating average sees, with P times fewer degrees of freedom) measures the density there.
    The ratio is applied where it exceeds 1 at significance COLOURED_P (white noise alone exceeds 1
    half of the time), else it is 1; a density below white is never used to shrink an SE."""
    C, n = left.shape
    with np.errstate(divide="ignore", invalid="ignore"):  # a constant channel: no noise, ratio 1
        power = np.abs(np.fft.rfft(left, axis=1)) ** 2 / (n * sigma ** 2)[:, None]
    nu = np.fft.rfftfreq(n, 1.0 / fs_hz)
    near = min(2.0 * fs_hz / n, 0.5 * f)
    r2 = np.zeros((C, K + 1))
    m = np.zeros(K + 1, dtype=np.int64)
    for k in range(K + 1):
        d = np.abs(nu - k * f)
        band = (d >= near * (1 - 1e-9)) & (d <= 0.5 * f * (1 + 1e-9)) & (nu > 0)
        m[k] = int(band.sum())
        if m[k]:
            r2[:, k] = power[:, band].mean(axis=1)
    dof = 2 * np.maximum(m, 1)
    beyond = (m > 0)[None] & (r2 > (chi2.ppf(1.0 - COLOURED_P, dof) / dof)[None])  # one ppf for every harmonic
    return np.where(beyond, np.sqrt(r2), 1.0)


def _dc_slopes(data: np.ndarray, fs_hz: float, spp: float, P: int, line_amp: np.ndarray, omegas: np.ndarray,
               f: float) -> list[tuple[float, float]]:
    """Least-squares line through the per-period means (the lines' share of each removed) against
    the periods' mid times: (slope per s, its SE from the residuals); NaN under three periods."""
    C = data.shape[0]
    if P < 3:
        return [(math.nan, math.nan)] * C
    # Exact integral of the samples' linear interpolant between period boundaries.
    cum = np.concatenate([np.zeros((C, 1)), np.cumsum(0.5 * (data[:, 1:] + data[:, :-1]), axis=1)], axis=1)
    u = np.arange(P + 1) * spp
    m = np.minimum(np.floor(u).astype(np.int64), data.shape[1] - 2)
    r = u - m
    at = cum[:, m] + r * data[:, m] + 0.5 * r ** 2 * (data[:, m + 1] - data[:, m])
    means = np.diff(at, axis=1) / spp  # (C, P)
    if omegas.size:
        wT = omegas / f
        share = np.exp(1j * np.outer(wT, np.arange(P))) * ((np.exp(1j * wT) - 1) / (1j * wT))[:, None]
        means = means - (line_amp.T @ share).real
    tm = (np.arange(P) + 0.5) / f
    tc = tm - tm.mean()
    sxx = float(tc @ tc)
    slope = means @ tc / sxx
    fit = means.mean(axis=1)[:, None] + slope[:, None] * tc[None]
    s2 = np.sum((means - fit) ** 2, axis=1) / (P - 2)
    return [(float(a), float(math.sqrt(v / sxx))) for a, v in zip(slope, s2)]
