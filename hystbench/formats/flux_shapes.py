"""B(t) over one period of a MagNet core-loss row, from its four duty fractions and its peak.

Why: a MagNet table row (``tests/data/real/magnet_*_shapes.csv``) gives the loss of a core under a
triangular or trapezoidal flux density, but only as ``duty_1..duty_4`` and the peak; a model that
takes B(t) needs the waveform itself.  It is rebuilt here the way MagNet builds it (the ``mag-net``
0.1.0 wheel, ``magnet/core.py`` ``core_loss_iGSE_trapezoidal`` and ``magnet/plots.py``
``cycle_points_trapezoidal``):

* the winding sees a full bridge's +V, 0, -V, 0 for the fractions ``duty_1, duty_2, duty_3,
  duty_4`` of the period, in that order, through a series capacitor that removes the mean: the
  levels are 1 - (d1 - d3), -(d1 - d3), -1 - (d1 - d3), -(d1 - d3) (in units of V);
* B is the integral of that voltage: piecewise linear, rising over ``duty_1``, falling over
  ``duty_3``; over ``duty_2`` and ``duty_4`` it is flat only when d1 == d3 (otherwise it drifts
  with the capacitor's offset, which MagNet's formula BN = BP (1 + d1 - d3) d3 / ((1 - d1 + d3) d1)
  expresses);
* ``flux_density_peak_T`` is the amplitude, half the peak-to-peak: max B = -min B = the peak.

The period starts where the rising segment starts (B = its minimum), as in MagNet.  A triangle is
``(d, 0, 1 - d, 0)``; MagNet's trapezoids all have ``duty_2 == duty_4``, the only case this rebuilds.
A sine row (all four ``-1``) is ``peak * sin(2 pi t / T)``, MagNet's ``core_loss_iGSE_sinusoidal``.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

__all__ = ["SINE_DUTY", "segment_steps", "shape_corners", "shape_flux_density"]

#: The duty tuple MagNet gives a sinusoidal row.
SINE_DUTY = (-1.0, -1.0, -1.0, -1.0)
_TOL = 1e-9  # MagNet's fractions are tenths written in float64: their sums are 1 within 2e-16


def _check(duty: Sequence[float], peak_t: float) -> tuple[float, float, float, float]:
    d = tuple(float(x) for x in duty)
    if len(d) != 4:
        raise ValueError(f"duty must have 4 fractions (duty_1..duty_4), got {len(d)}")
    if not (np.isfinite(peak_t) and peak_t > 0):
        raise ValueError(f"the peak flux density must be a finite number > 0, got {peak_t!r}")
    if d == SINE_DUTY:
        return d  # type: ignore[return-value]
    if not all(np.isfinite(x) and 0.0 <= x <= 1.0 for x in d) or abs(sum(d) - 1.0) > _TOL:
        raise ValueError(f"duty {d} must be four fractions in [0, 1] summing to 1 (or all -1 for a sine)")
    if d[0] <= 0 or d[2] <= 0:
        raise ValueError(f"duty {d}: duty_1 (rising) and duty_3 (falling) must be > 0")
    if abs(d[1] - d[3]) > _TOL:
        raise ValueError(f"duty {d}: MagNet's trapezoids have duty_2 == duty_4; another waveform is not rebuilt")
    return d  # type: ignore[return-value]


def segment_steps(duty: np.ndarray) -> np.ndarray:
    """How far b = B / B_pk moves over each of the four segments, for every row of a (rows, 4) array of
    triangular/trapezoidal duties (the bridge's levels through the series capacitor, scaled so that b
    spans -1 .. 1); vectorised, for the rows of a whole table."""
    d = np.atleast_2d(np.asarray(duty, dtype=np.float64))
    offset = d[:, 0] - d[:, 2]  # the mean the series capacitor takes away
    volts = np.stack([1.0 - offset, -offset, -1.0 - offset, -offset], axis=1)
    step = volts * d
    corners = np.concatenate([np.zeros((d.shape[0], 1)), np.cumsum(step, axis=1)], axis=1)
    return step * (2.0 / (corners.max(axis=1) - corners.min(axis=1)))[:, None]


def shape_corners(duty: Sequence[float], flux_density_peak_t: float) -> tuple[np.ndarray, np.ndarray]:
    """The corners of a triangular/trapezoidal B(t): phases t/T (0 ... 1, five points, a repeated
    phase where a fraction is 0) and B there (T); B(1) == B(0).  Not for a sine row."""
    d1, d2, d3, d4 = _check(duty, flux_density_peak_t)
    if (d1, d2, d3, d4) == SINE_DUTY:
        raise ValueError("a sine row has no corners; use shape_flux_density")
    b = np.concatenate([[0.0], np.cumsum(segment_steps(np.array([d1, d2, d3, d4]))[0])])
    b = flux_density_peak_t * (b - (b.max() + b.min()) / 2.0)
    b[-1] = b[0]  # closes exactly (the levels have zero mean), without the rounding of the sum
    return np.concatenate([[0.0], np.cumsum([d1, d2, d3, d4])]), b


def shape_flux_density(duty: Sequence[float], flux_density_peak_t: float, phase: np.ndarray | float) -> np.ndarray:
    """B (T) at the phases t/T (any real: taken modulo 1) of a MagNet row's waveform."""
    ph = np.mod(np.asarray(phase, dtype=np.float64), 1.0)
    d = _check(duty, flux_density_peak_t)
    if d == SINE_DUTY:
        return flux_density_peak_t * np.sin(2.0 * np.pi * ph)
    t, b = shape_corners(d, flux_density_peak_t)
    t[-1] = 1.0
    keep = np.concatenate([[True], np.diff(t) > 0])  # np.interp needs increasing phases
    return np.interp(ph, t[keep], b[keep])
