"""The flux from a raw sense-coil voltage, for recordings that carry ``sense_V`` and no ``flux_Wb``.

The recording format lets a bench record the sense coil's voltage before any integrator ("the
project integrates it itself"): a bench without a flux integrator, or one whose integrator is
distrusted.  Every analysis that needs the flux (the method's delays, identification, the force
models, the diagnosis) takes it from :func:`with_flux`, integrated the same way.

- Faraday, in the project's sign convention (the rig presets' ``sense.turns``): sense_V = -N dphi/dt,
  so phi = -(1/N) integral of sense_V dt, with N the sidecar's ``sense_turns``.  A coil wired the
  other way gives a flux in antiphase with the current, which no iron does: refused, not guessed.
- A glitch in the voltage would be a step in its integral, which no later outlier search can find:
  the voltage's own outliers (off its fitted waveform, as the method finds a channel's) are bridged
  by straight lines first, and named in the sidecar the analyses see (``sense_V_outliers``).
- The integral is the trapezoidal rule, whose phase is exactly -90 deg at every frequency (a bilinear
  integrator: no delay between the flux and the current it is compared with), with its gain error
  1 - (w T)^2 / 12 undone by a symmetric three-tap correction (no phase of its own): what is left is
  11 (w T)^4 / 720, 3e-5 at 3.4 kHz sampled at 100 kHz.
- AC only, as an integrator's output: the voltage's offset, and an offset that drifts linearly, are a
  quadratic in the integral, fitted together with the harmonics of the nominal frequency and taken out
  (a plain mean leaves a ramp where the record is not a whole number of periods: 1.3e-2 of the
  amplitude at 333 Hz over two periods on 100 kHz).
"""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np

from ..errors import RecordingError
from ..formats.recording import Recording
from .estimation import estimation_errors, find_outliers

__all__ = ["integrate_sense_voltage", "with_flux", "FLUX_FROM", "OUTLIERS", "TREND_HARMONICS"]

#: The sidecar key that says the flux was integrated here, and from what.
FLUX_FROM = "flux_Wb_from"
#: The sidecar key listing the voltage's samples bridged as outliers.
OUTLIERS = "sense_V_outliers"
#: Harmonics of the nominal frequency fitted beside the trend (a sense voltage carries a flux's odd
#: harmonics times their order), and those the outlier search fits.
TREND_HARMONICS = 15
OUTLIER_HARMONICS = tuple(range(1, 10))
#: At most this share of the voltage's samples may be bridged (the method's limit for a channel).
MAX_BRIDGED = 0.01
_CHUNK = 65536  # samples per block of the trend's normal equations: bounded memory on long records


def integrate_sense_voltage(sense_v: np.ndarray, fs_hz: float, turns: float, frequency_hz: float) -> np.ndarray:
    """The flux (Wb, AC only) through a coil of ``turns`` whose voltage is ``sense_v``, sampled at
    ``fs_hz``, excited at ``frequency_hz`` (module docstring)."""
    v = np.asarray(sense_v, dtype=float)
    phi = np.empty_like(v)
    phi[0] = 0.0
    np.cumsum((0.5 / fs_hz) * (v[1:] + v[:-1]), out=phi[1:])
    if v.size >= 4:  # the trapezoid's gain 1 - (wT)^2/12 + ..., undone by 1 - (second difference)/12
        d2 = phi[2:] - 2.0 * phi[1:-1] + phi[:-2]  # at each end extrapolated from its two neighbours
        phi -= np.concatenate(([2 * d2[0] - d2[1]], d2, [2 * d2[-1] - d2[-2]])) / 12.0
    flux = -phi / turns
    return flux - _trend(flux, fs_hz, frequency_hz)


def _trend(x: np.ndarray, fs_hz: float, frequency_hz: float) -> np.ndarray:
    """The quadratic in time of ``x``, fitted by least squares together with the harmonics of
    ``frequency_hz`` below the Nyquist frequency (normal equations over blocks of samples)."""
    n = x.size
    k_max = max(1, min(TREND_HARMONICS, math.ceil(fs_hz / (2 * frequency_hz)) - 1))
    w = 2 * np.pi * frequency_hz / fs_hz * np.arange(1, k_max + 1)

    def basis(i0: int, i1: int) -> np.ndarray:
        i = np.arange(i0, i1, dtype=float)
        s = 2 * i / max(n - 1, 1) - 1  # [-1, 1]: Legendre polynomials stay well conditioned
        c, d = np.cos(np.outer(i, w)), np.sin(np.outer(i, w))
        # each harmonic also times s: its frequency a few ppm off the nominal (a clock's), which the
        # quadratic would otherwise take a share of (1.3e-4 of the amplitude at 40 ppm over 48 periods)
        return np.column_stack([np.ones_like(s), s, 1.5 * s * s - 0.5, c, d, s[:, None] * c, s[:, None] * d])

    p = 3 + 4 * k_max
    ata, aty = np.zeros((p, p)), np.zeros(p)
    for i0 in range(0, n, _CHUNK):
        A = basis(i0, min(n, i0 + _CHUNK))
        ata += A.T @ A
        aty += A.T @ x[i0:i0 + A.shape[0]]
    coef = np.linalg.lstsq(ata, aty, rcond=None)[0]
    s = 2 * np.arange(n) / max(n - 1, 1) - 1
    return coef[0] + coef[1] * s + coef[2] * (1.5 * s * s - 0.5)


def with_flux(rec: Recording, *, required: bool = True) -> Recording:
    """``rec`` itself when it has ``flux_Wb`` or no ``sense_V``; else a copy with ``flux_Wb``
    integrated from ``sense_V`` (its sidecar saying so in ``flux_Wb_from``, and naming the voltage's
    bridged outliers in ``sense_V_outliers``).  Without the sidecar's ``sense_turns`` it is refused,
    or, not ``required``, ``rec`` is handed back as it is (the diagnosis goes on without a flux)."""
    if "flux_Wb" in rec.channels or "sense_V" not in rec.channels:
        return rec
    where = _where(rec)
    turns = rec.metadata.get("sense_turns")
    if turns is None:
        if not required:
            return rec
        raise RecordingError(f"{where}: the recording has sense_V and no flux_Wb; integrating the sense coil's "
                             "voltage into a flux needs its turns: add 'sense_turns' to the sidecar")
    if isinstance(turns, bool) or not isinstance(turns, (int, float)) or not (math.isfinite(turns) and turns > 0):
        raise RecordingError(f"{where}: 'sense_turns' must be a positive number of turns, got {turns!r}")
    periods = rec.n * rec.frequency_hz / rec.fs_hz
    if periods < 2.0:
        raise RecordingError(f"{where}: sense_V covers {periods:.2f} periods of {rec.frequency_hz:g} Hz; integrating "
                             "it into a flux needs at least two (its offset is told from its signal over whole periods)")
    if np.ptp(rec.channels["sense_V"]) == 0.0:
        raise RecordingError(f"{where}: sense_V is flat (every sample {float(rec.channels['sense_V'][0])!r}): no flux "
                             "to integrate")
    v, bridged = _bridge_outliers(rec, where)
    flux = integrate_sense_voltage(v, rec.fs_hz, float(turns), rec.frequency_hz)
    _check_polarity(rec, flux, where)
    meta = {**rec.metadata, FLUX_FROM: f"sense_V integrated by hystbench (sense_V = -{turns:g} dphi/dt)"}
    if bridged.size:
        meta[OUTLIERS] = bridged.tolist()
    return replace(rec, channels={**rec.channels, "flux_Wb": flux}, metadata=meta)


def _where(rec: Recording) -> str:
    """What a refusal names: the sidecar of a recording's files, or the log segment."""
    point = f"the {rec.rig} recording at {rec.frequency_hz:g} Hz"
    if rec.path is None:
        return point
    if Path(rec.path).suffix.lower() == ".mcap":  # a log's segment: its sidecar is a record inside it
        return f"{rec.path}: {point}"
    return f"{rec.path}.json"


def _bridge_outliers(rec: Recording, where: str) -> tuple[np.ndarray, np.ndarray]:
    """The voltage with its outliers (far off its fitted waveform) replaced by straight lines between
    their good neighbours, and their indices; more than MAX_BRIDGED of them is a broken channel."""
    v = np.asarray(rec.channels["sense_V"], dtype=float)
    with estimation_errors(where):
        (mask,), _ = find_outliers([v], rec.fs_hz, rec.frequency_hz, harmonics=OUTLIER_HARMONICS,
                                   names=["channel 'sense_V'"])
    bad = np.flatnonzero(mask)
    if bad.size > MAX_BRIDGED * v.size:
        raise RecordingError(f"{where}: sense_V has {bad.size} samples far off its fitted waveform (first at "
                             f"{', '.join(map(str, bad[:5]))}); more than {100 * MAX_BRIDGED:g} % are not glitches: "
                             "is the channel broken?")
    if bad.size:
        good = np.flatnonzero(~mask)
        v = v.copy()
        v[bad] = np.interp(bad, good, v[good])
    return v, bad


def _check_polarity(rec: Recording, flux: np.ndarray, where: str) -> None:
    """A flux more than 90 deg from the current at the fundamental is a coil wired the other way
    round (an iron's lag is tens of degrees at most)."""
    if "current_A" not in rec.channels:
        return
    t = np.arange(rec.n) * (2 * np.pi * rec.frequency_hz / rec.fs_hz)
    e = np.exp(-1j * t)
    i = complex(np.dot(np.asarray(rec.channels["current_A"], dtype=float), e))
    p = complex(np.dot(flux, e))
    if abs(i) > 0 and abs(p) > 0 and (p * i.conjugate()).real < 0:
        lag = math.degrees(np.angle(p * i.conjugate()))
        raise RecordingError(f"{where}: the flux integrated from sense_V is {lag:+.0f} deg from current_A at "
                             f"{rec.frequency_hz:g} Hz: the sense coil is wired the other way round from sense_V = "
                             "-turns dphi/dt (the project's convention); negate the sense_V column")
