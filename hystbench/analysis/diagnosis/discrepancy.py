"""The baseline is allowed to be wrong, explicitly: a smooth model discrepancy per path of the bench.

A real bench is never its simulation.  Kennedy and O'Hagan's answer is to give the calibrated model an
explicit discrepancy term with a prior, fitted jointly with the physical parameters, so that what a
physical parameter cannot reach goes to the discrepancy (and is reported) instead of to a 2.6x airgap.
Here the discrepancy is linear in its coefficients (columns of the calibration's least squares), each
with a Gaussian prior: the prior is what it is charged.  The bench's structure says where it may act:

- **the iron** (current to flux), per rig and amplitude: each flux harmonic may move by a complex
  number smooth in frequency (constant and slope in log f).  A real iron's loop and its eddy currents
  are never the preset material's; they depend on the rig and the amplitude and vary slowly with f.
  The force follows the flux through the force law, so the iron's misfit reaches the force rows only as
  the force law carries it (``dF = g'(phi) dphi``, in time, per record): it does not give the force's
  own path (the load cell, the charge amplifier: force behind flux) any freedom;
- **the force law** (flux to force), per rig and amplitude: each force harmonic may move by a complex
  number that is the same at every frequency (an instantaneous law has no frequency of its own).

- **the amplifier** (command to current), per rig: the command's fundamental may move by a complex
  number smooth in frequency (1, f, f^2 over the rig's highest frequency: a transconductance amplifier's
  bandwidth and its load, which the simulation takes as ideal).

Nothing else gets a discrepancy: a channel's delay, the instrument's response, the day's clock and the
lines that are not harmonics keep the noise floor, which is where the catalogue's other effects show.
"""

from __future__ import annotations

import math
from typing import Any, Mapping, Sequence

import numpy as np

from .features import RecordFeatures
from .fit import Column
from .vector import CHANNELS, Layout, record_harmonics

__all__ = ["discrepancy_columns", "IRON_PRIOR", "LAW_PRIOR", "AMPLIFIER_PRIOR"]

#: Prior width of each iron coefficient (constant, slope over the group's log-frequency span), as a
#: share of the flux's largest harmonic in the group.
IRON_PRIOR = 0.05
#: Prior width of each force-law coefficient, as a share of the force's largest harmonic in the group.
LAW_PRIOR = 0.05
#: Prior width of each amplifier coefficient (a relative change of the command per ampere).
AMPLIFIER_PRIOR = 0.3
_PHASES = 64  # points per period where the force law is linearised
PREFIX = "discrepancy."


def discrepancy_columns(data: Sequence[RecordFeatures], base_effects: Mapping[str, Mapping[str, Any]],
                        layout: Layout, m0: np.ndarray) -> list[Column]:
    """The discrepancy's columns around the model ``m0`` (module docstring), for the rigs whose
    baseline has an iron (``static_hysteresis``)."""
    groups: dict[tuple[str, float], list[int]] = {}
    for r, f in enumerate(data):
        if "static_hysteresis" in base_effects.get(f.rig, {}) and "flux_Wb" in f.harmonics:
            groups.setdefault((f.rig, round(f.current_pp_a, 6)), []).append(r)
    K = int(layout.harmonic.max(initial=0))
    flux, force = CHANNELS.index("flux_Wb"), CHANNELS.index("force_N")
    cols: list[Column] = []
    for (rig, amp), recs in groups.items():
        where = f"{rig}@{amp:g}A"
        in_group = np.isin(layout.record, recs)
        logf = np.log([data[r].frequency_hz for r in recs])
        span = max(float(np.ptp(logf)), math.log(2.0))
        slope = {r: (lf - float(np.mean(logf))) / span for r, lf in zip(recs, logf)}
        carry = {r: _force_law_slope(m0, layout, r, K) for r in recs}
        flux_scale = float(np.max(layout.scale[in_group & (layout.channel == flux)], initial=0.0))
        force_rows = in_group & (layout.channel == force)
        force_scale = float(np.max(layout.scale[force_rows], initial=0.0))
        for k in range(0, K + 1):
            for part in (0, 1):
                if k == 0 and part == 1:
                    continue
                if k == 0:  # the force law's DC only: the flux's DC is not measured
                    sel = force_rows & (layout.harmonic == 0)
                    if sel.any() and force_scale > 0:
                        v = np.zeros(m0.size)
                        v[np.flatnonzero(sel)] = 1.0
                        cols.append(Column(f"{PREFIX}law.{where}.k0", v, prior=LAW_PRIOR * force_scale))
                    continue
                unit = 1.0 if part == 0 else 1j
                for term in ("const", "slope"):
                    v = np.zeros(m0.size)
                    for r in recs:
                        w = 1.0 if term == "const" else slope[r]
                        _set(v, layout, r, flux, k, w * unit)
                        if carry[r] is not None:
                            _add_harmonics(v, layout, r, force, carry[r](k, w * unit))
                    if flux_scale > 0 and np.any(v):
                        cols.append(Column(f"{PREFIX}iron.{where}.k{k}.{'im' if part else 're'}.{term}", v,
                                           prior=IRON_PRIOR * flux_scale))
                if force_scale > 0:
                    sel = force_rows & (layout.harmonic == k) & (layout.part == part)
                    if sel.any():
                        v = np.zeros(m0.size)
                        v[np.flatnonzero(sel)] = 1.0
                        cols.append(Column(f"{PREFIX}law.{where}.k{k}.{'im' if part else 're'}", v,
                                           prior=LAW_PRIOR * force_scale))
    cols += _amplifier_columns(data, layout, m0)
    return cols


def _amplifier_columns(data: Sequence[RecordFeatures], layout: Layout, m0: np.ndarray) -> list[Column]:
    """The command's fundamental per rig times a complex factor 1 + c(f), c = c0 + c1 f/f_max + c2
    (f/f_max)^2: a response, so it scales with the amplitude."""
    command = CHANNELS.index("command_V")
    cols = []
    for rig in dict.fromkeys(f.rig for f in data):
        recs = [r for r, f in enumerate(data) if f.rig == rig]
        f_max = max(data[r].frequency_hz for r in recs)
        rows = np.isin(layout.record, recs) & (layout.channel == command) & (layout.harmonic == 1)
        if not rows.any():
            continue
        for part in (0, 1):
            for power in (0, 1, 2):
                v = np.zeros(m0.size)
                for r in recs:
                    c = record_harmonics(m0, layout, r).get("command_V")
                    if c is None:
                        continue
                    w = (data[r].frequency_hz / f_max) ** power
                    _set(v, layout, r, command, 1, w * c[1] * (1.0 if part == 0 else 1j))
                cols.append(Column(f"{PREFIX}amplifier.{rig}.f{power}.{'im' if part else 're'}", v,
                                   prior=AMPLIFIER_PRIOR))
    return cols


def _wave(h: np.ndarray, n: int = _PHASES) -> np.ndarray:
    """One period at n phases from harmonics (X_0 + sum Re(X_k e^{ikwt}))."""
    spec = np.zeros(n // 2 + 1, complex)
    spec[0] = h[0] * n
    spec[1:h.size] = h[1:] * n / 2
    return np.fft.irfft(spec, n)


def _force_law_slope(m: np.ndarray, layout: Layout, record: int, K: int):
    """For one record, a function (k, dphi_k) -> the force's harmonic change that a change dphi_k of
    the flux's k-th harmonic makes through the model's force law (F ~ a0 + a1 phi + a2 phi^2 fitted on
    the model's own period); None without flux or force."""
    h = record_harmonics(m, layout, record)
    phi, F = h.get("flux_Wb"), h.get("force_N")
    if phi is None or F is None:
        return None
    phi[0] = 0.0  # the integrator's DC is where it was reset: the law's a0, a1 hold the bias
    p, fw = _wave(phi), _wave(F)
    scale = float(np.max(np.abs(p))) or 1.0
    x = p / scale
    a = np.linalg.lstsq(np.column_stack([np.ones_like(x), x, x * x]), fw, rcond=None)[0]
    gain = (a[1] + 2 * a[2] * x) / scale  # dF/dphi along the period
    theta = 2 * np.pi * np.arange(_PHASES) / _PHASES

    def carried(k: int, dphi: complex) -> np.ndarray:
        dF = gain * np.real(dphi * np.exp(1j * k * theta))
        spec = np.fft.rfft(dF) / _PHASES
        out = np.zeros(K + 1, complex)
        out[0] = spec[0].real
        out[1:] = 2 * spec[1:K + 1]
        return out

    return carried


def _set(v: np.ndarray, layout: Layout, record: int, channel: int, k: int, value: complex) -> None:
    sel = (layout.record == record) & (layout.channel == channel) & (layout.harmonic == k)
    for i in np.flatnonzero(sel):
        v[i] = value.real if layout.part[i] == 0 else value.imag


def _add_harmonics(v: np.ndarray, layout: Layout, record: int, channel: int, h: np.ndarray) -> None:
    sel = (layout.record == record) & (layout.channel == channel)
    for i in np.flatnonzero(sel):
        k = layout.harmonic[i]
        v[i] += h[k].real if layout.part[i] == 0 else h[k].imag
