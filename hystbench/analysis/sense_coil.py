"""The flux from a raw sense-coil voltage, for recordings that carry ``sense_V`` and no ``flux_Wb``.

The recording format lets a bench record the sense coil's voltage before any integrator ("the
project integrates it itself"): a bench without a flux integrator, or one whose integrator is
distrusted.  Every analysis that needs the flux takes it from here, integrated the same way.

- Faraday, in the project's sign convention (the rig presets' ``sense.turns``): sense_V = -N dphi/dt,
  so phi = -(1/N) integral of sense_V dt, with N the sidecar's ``sense_turns`` (required: a flux
  off by the turns would be a wrong flux, not a missing one).
- The integral is the trapezoidal rule, whose phase is exactly -90 deg at every frequency (a bilinear
  integrator: no delay between the flux and the current it is compared with), with its gain error
  1 - (w T)^2 / 12 undone by a symmetric three-tap correction (no phase of its own): what is left is
  11 (w T)^4 / 720, 3e-5 at 3.4 kHz sampled at 100 kHz.
- The flux is AC only, like an integrator's: the voltage's DC is taken out first (an ADC offset would
  otherwise ramp), the flux's after, each the mean over the whole periods of the nominal frequency
  weighted by a Hann window (with two periods or more): a clock a few ppm off the nominal leaves
  those periods a fraction of a sample from whole, and the window keeps that fraction out of the DC
  (plain means left the flux a ramp that moved its fundamental by 5e-5 at 40 ppm).
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
from scipy import signal

from ..errors import RecordingError
from ..formats.recording import Recording

__all__ = ["integrate_sense_voltage", "with_flux", "FLUX_FROM"]

#: The sidecar key that says the flux was integrated here, and from what.
FLUX_FROM = "flux_Wb_from"


def integrate_sense_voltage(sense_v: np.ndarray, fs_hz: float, turns: float, frequency_hz: float) -> np.ndarray:
    """The flux (Wb, AC only) through a coil of ``turns`` whose voltage is ``sense_v``, sampled at
    ``fs_hz``; the means are taken over the whole periods of ``frequency_hz`` (module docstring)."""
    v = np.asarray(sense_v, dtype=float)
    whole, periods = _whole_periods(v.size, fs_hz, frequency_hz)
    v = v - _dc(v[:whole], periods)
    dt = 1.0 / fs_hz
    phi = np.empty_like(v)
    phi[0] = 0.0
    np.cumsum(0.5 * dt * (v[1:] + v[:-1]), out=phi[1:])
    # the trapezoid's gain 1 - (wT)^2/12 + ..., undone by 1 - (second difference)/12 (at each end, the
    # second difference extrapolated from its two neighbours)
    corrected = phi.copy()
    if v.size >= 4:
        d2 = phi[2:] - 2.0 * phi[1:-1] + phi[:-2]
        corrected -= np.concatenate(([2 * d2[0] - d2[1]], d2, [2 * d2[-1] - d2[-2]])) / 12.0
    flux = -corrected / turns
    return flux - _dc(flux[:whole], periods)


def _whole_periods(n: int, fs_hz: float, frequency_hz: float) -> tuple[int, int]:
    """Samples in the whole periods of ``frequency_hz`` from the start, and how many periods (all the
    samples, and 0, when under one)."""
    per = fs_hz / frequency_hz
    periods = math.floor(n / per)
    return (n, 0) if periods < 1 else (max(2, min(n, round(periods * per))), periods)


def _dc(x: np.ndarray, periods: int) -> float:
    """The mean of ``x`` (whole periods), Hann-weighted when two periods or more (a periodic Hann
    window is zero at every harmonic from the second bin on; over one period the plain mean is)."""
    if periods < 2:
        return float(x.mean())
    w = signal.windows.hann(x.size, sym=False)
    return float(np.dot(w, x) / w.sum())


def with_flux(rec: Recording) -> Recording:
    """``rec`` itself when it has ``flux_Wb`` or no ``sense_V``; else a copy with ``flux_Wb``
    integrated from ``sense_V`` (its sidecar saying so in ``flux_Wb_from``)."""
    if "flux_Wb" in rec.channels or "sense_V" not in rec.channels:
        return rec
    where = f"{rec.path}.json" if rec.path is not None else "recording"
    turns = rec.metadata.get("sense_turns")
    if turns is None:
        raise RecordingError(f"{where}: the recording has sense_V and no flux_Wb; integrating the sense coil's "
                             "voltage into a flux needs its turns: add 'sense_turns' to the sidecar")
    if isinstance(turns, bool) or not isinstance(turns, (int, float)) or not (math.isfinite(turns) and turns > 0):
        raise RecordingError(f"{where}: 'sense_turns' must be a positive number of turns, got {turns!r}")
    flux = integrate_sense_voltage(rec.channels["sense_V"], rec.fs_hz, float(turns), rec.frequency_hz)
    meta = {**rec.metadata, FLUX_FROM: f"sense_V integrated by hystbench (sense_V = -{turns:g} dphi/dt)"}
    return replace(rec, channels={**rec.channels, "flux_Wb": flux}, metadata=meta)
