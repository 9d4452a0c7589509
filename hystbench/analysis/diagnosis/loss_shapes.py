"""The waveform side of the loss separation: how a rate term's energy per cycle scales with the shape of
B(t), and where the held-out residual sits among MagNet's triangular and trapezoidal shapes.

With B(t) = B_pk b(t/T), a loss term whose field grows as |dB/dt|^(p-1) (so its power as |dB/dt|^p)
takes per cycle W = k f^(p-1) B_pk^p S_p, with the shape factor

    S_p = int_0^1 |b'(phi)|^p dphi / int_0^1 |2 pi cos 2 pi phi|^p dphi,
    int_0^1 |2 pi cos 2 pi phi|^p dphi = (2 pi)^p Gamma((p + 1)/2) / (sqrt(pi) Gamma(p/2 + 1)),

normalised so that a sine has S_p = 1 (its k is the sine's).  This is Bertotti's loss separation
carried to arbitrary waveforms (G. Bertotti, "General properties of power losses in soft
ferromagnetic materials", IEEE Trans. Magn. 24(1), 1988: the classical term's p = 2, the excess
term's p = 1.5) and, for a free Steinmetz term k f^gamma B^delta, the improved generalised Steinmetz
equation's p = alpha = 1 + gamma (K. Venkatachalam, C. R. Sullivan, T. Abdallah, H. Tacca, "Accurate
prediction of ferrite core loss with nonsinusoidal waveforms using only Steinmetz parameters", IEEE
COMPEL 2002; J. Li, T. Abdallah, C. R. Sullivan, "Improved calculation of core loss with
nonsinusoidal waveforms", IEEE IAS 2001).  A rate-independent hysteresis loss depends on the B
excursion only: S = 1 for every shape of the same B_pk.

For MagNet's piecewise-linear b (:mod:`~hystbench.formats.flux_shapes`, rebuilt here vectorised over
rows) the integral is closed: sum over segments of d_i^(1-p) |delta b_i|^p, a segment of d_i = 0
contributing nothing.  Losses during the flat segments (magnetic relaxation, the i2GSE of
J. Muehlethaler, J. Biela, J. W. Kolar, A. Ecklebe, "Improved core-loss calculation for magnetic
components employed in power electronic systems", IEEE Trans. Power Electron. 27(2), 2012) are a term of
their own (:mod:`.loss_terms`, ``flat_segment_relaxation``); unmodelled, they show in :func:`locate_shapes`
as a residual growing with the share between the ramps.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from ...formats.flux_shapes import segment_steps

__all__ = ["sine_integral", "shape_factor", "calibration_shapes", "shape_group", "locate_shapes"]

#: The symmetric triangle (duty_1 = duty_3 = 0.5), calibrated on with the sines.
SYMMETRIC_TRIANGLE = (0.5, 0.0, 0.5, 0.0)
_TOL = 1e-9


def sine_integral(p: float) -> float:
    """int_0^1 |2 pi cos 2 pi phi|^p dphi (the sine's, closed form)."""
    return (2.0 * math.pi) ** p * math.gamma((p + 1.0) / 2.0) / (math.sqrt(math.pi) * math.gamma(p / 2.0 + 1.0))


def _is_sine(duty: np.ndarray) -> np.ndarray:
    return np.all(duty == -1.0, axis=1)


def shape_factor(duty: np.ndarray, p: float) -> np.ndarray:
    """S_p of every row of a (rows, 4) duty array (all -1: a sine, S_p = 1 exactly)."""
    duty = np.atleast_2d(np.asarray(duty, dtype=np.float64))
    sine = _is_sine(duty)
    d = np.where(sine[:, None], 0.25, duty)  # any valid shape in the sine rows; overwritten below
    step = segment_steps(d)
    live = d > 0
    seg = np.where(live, np.where(live, d, 1.0) ** (1.0 - p) * np.abs(step) ** p, 0.0)
    s = seg.sum(axis=1) / sine_integral(p)
    s[sine] = 1.0
    return s


def calibration_shapes(duty: np.ndarray) -> np.ndarray:
    """Rows the rate-independent baseline may be calibrated on: sines and symmetric triangles."""
    return _is_sine(duty) | np.all(np.abs(duty - np.array(SYMMETRIC_TRIANGLE)) < _TOL, axis=1)


def shape_group(duty: np.ndarray) -> np.ndarray:
    """``sine``, ``triangle`` (no time between the ramps) or ``trapezoid`` per row."""
    between = duty[:, 1] + duty[:, 3]
    return np.where(_is_sine(duty), "sine", np.where(between > _TOL, "trapezoid", "triangle"))


def _rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(x**2))) if x.size else float("nan")


def locate_shapes(duty: np.ndarray, before: np.ndarray, after: np.ndarray, held: np.ndarray, noise: float,
                  model: float) -> dict[str, Any]:
    """The held-out residual (log10 W_meas / W_model) per duty tuple and per shape group, before (the
    rate-independent baseline) and after (with the named terms, shape factors applied); z of the mean
    after against sqrt(noise^2/n + model^2); the after-residual's slope against the share of the
    period between the ramps (duty_2 + duty_4), over every triangle and trapezoid and over those whose
    B is flat there (duty_1 == duty_3: ``flat_trend``).  On MagNet's tuples a larger flat share also
    means steeper ramps (d1 = d3 = (1 - share)/2), so the flat trend is not relaxation's alone: compare
    the steep triangles (0.1, 0, 0.9, 0), which have no flat time, in ``shapes``."""
    u, inv = np.unique(duty, axis=0, return_inverse=True)
    inv = inv.ravel()
    shapes = []
    for k, d in enumerate(u):
        m = held & (inv == k)
        n = int(m.sum())
        if not n:
            continue
        mean = float(after[m].mean())
        shapes.append({"duty": [float(x) for x in d], "group": str(shape_group(d[None])[0]),
                       "between_ramps_share": 0.0 if d[0] == -1 else float(d[1] + d[3]),
                       "flat_between_ramps": bool(d[0] != -1 and d[1] > 0 and abs(d[0] - d[2]) < _TOL),
                       "held_out": n, "rms_before_log10": _rms(before[m]), "rms_after_log10": _rms(after[m]),
                       "mean_after_log10": mean, "z_after": mean / math.sqrt(noise**2 / n + model**2)})
    groups = {}
    g = shape_group(duty)
    for name in ("sine", "triangle", "trapezoid"):
        m = held & (g == name)
        if m.any():
            b4, af = _rms(before[m]), _rms(after[m])
            groups[name] = {"held_out": int(m.sum()), "residual_before_log10": b4, "residual_after_log10": af,
                            "residual_before": b4 / noise, "residual_after": af / noise,
                            "improvement": b4 / af if af > 0 else None}
    shaped = held & (g != "sine")
    flat = shaped & (np.abs(duty[:, 0] - duty[:, 2]) < _TOL)  # B truly flat between the ramps (or no time there)
    worst = sorted(shapes, key=lambda s: s["rms_after_log10"], reverse=True)
    return {"shapes": shapes, "groups": groups, "between_ramps_trend": _share_trend(duty, after, shaped),
            "flat_trend": _share_trend(duty, after, flat), "missed_most": [s["duty"] for s in worst[:3]]}


def _share_trend(duty: np.ndarray, after: np.ndarray, rows: np.ndarray) -> dict[str, float] | None:
    """The slope (with its standard error) of the residual against duty_2 + duty_4 over ``rows``."""
    x = duty[rows, 1] + duty[rows, 3]
    if x.size <= 3 or np.ptp(x) == 0:
        return None
    a = np.column_stack([np.ones_like(x), x])
    coef, *_ = np.linalg.lstsq(a, after[rows], rcond=None)
    r = after[rows] - a @ coef
    se = np.sqrt(np.diag(np.linalg.pinv(a.T @ a) * float(r @ r) / max(r.size - 2, 1)))
    return {"slope_log10_per_share": float(coef[1]), "slope_std": float(se[1]), "rows": int(x.size)}
