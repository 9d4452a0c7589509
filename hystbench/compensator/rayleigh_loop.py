"""A Rayleigh-loop model of the iron: closed-form branches whose width grows with the amplitude.

Rayleigh's law (IEC 60050-221-03-32) describes the iron's loops at low fields: from each turning
point the branch is a parabola, so a loop of half-amplitude A has a width growing as A^2 and a
loss as A^3.  In the coordinates of the force model (j: the current the airgaps see, d: the
iron's share of the coil current) one period of j with its turning points at its maximum and
minimum, midpoint m and half-range A, x = j - m and s = +1 rising, -1 falling:

    d = delta + (a0 + a1 A) x + e x^2 - s (c / 2) ((x + s A)^2 - 2 A^2),   i = j + d + tau dj/dt

The loop closes at both tips; ``e`` is the curvature of the bias point's magnetisation curve (the
magnet's).  Linear in (delta, a0, a1, e, c, tau): one weighted least-squares fit of a sweep, with
standard errors.  It knows one maximum and one minimum per period only (a reference with inner
turning points is taken as its outer loop); :mod:`.hysteresis_eddy` keeps the full memory, and
:mod:`.identify` chooses between them by held-out error.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Sequence

import numpy as np

from .errors import CompensatorError
from .lsq import linear_fit
from .periodic import derivative, harmonics
from .seen_current import SeenCurrentModel
from .static import StaticLaw

__all__ = ["RayleighLoopModel", "fit_rayleigh_loop", "TERMS"]

TERMS = ("delta_A", "a0", "a1_per_A", "e_per_A", "c_per_A", "tau_s")
_MAX_ITER, _TOL_A = 60, 1e-10
#: A fixed point stalled below this is accepted: where a turning point sits between two samples the
#: branch direction flips with it, so the map has steps of a few nA (force error < 1e-6 of range).
_STALL_A = 1e-6


def _loop_basis(j: np.ndarray) -> tuple[np.ndarray, np.ndarray, float, float]:
    """(x, s, m, A) of one period of j: its turning points are its maximum and minimum."""
    lo, hi = int(np.argmin(j)), int(np.argmax(j))
    m, a = 0.5 * (j[hi] + j[lo]), 0.5 * (j[hi] - j[lo])
    k = np.arange(j.size)
    rising = ((k - lo) % j.size) < ((hi - lo) % j.size)
    return j - m, np.where(rising, 1.0, -1.0), m, a


def _columns(j: np.ndarray, frequency_hz: float) -> np.ndarray:
    x, s, _, a = _loop_basis(j)
    return np.stack([np.ones_like(j), x, a * x, x * x, -0.5 * s * ((x + s * a) ** 2 - 2 * a * a),
                     derivative(j, frequency_hz)], axis=1)


@dataclass
class RayleighLoopModel(SeenCurrentModel):
    """See the module docstring; ``coef`` are the values of :data:`TERMS`."""

    law: StaticLaw
    coef: tuple[float, ...]
    report: dict = field(default_factory=dict)
    kind = "best"
    name = "rayleigh_loop"

    def current_for(self, j_a: np.ndarray, frequency_hz: float) -> np.ndarray:
        """The coil current (one period) that makes the airgaps see ``j_a``."""
        j = np.asarray(j_a, float)
        return j + _columns(j, frequency_hz) @ np.asarray(self.coef)

    def effective_current(self, current_a: np.ndarray, frequency_hz: float) -> np.ndarray:
        """j for one period of the coil current: the linear and eddy terms exact per harmonic, the
        loop's curvature by fixed point (it is a few % of j)."""
        i = np.asarray(current_a, float)
        _, a0, a1, _, _, tau = self.coef
        j = i.copy()
        for _ in range(_MAX_ITER):
            lin = a0 + a1 * _loop_basis(j)[3]  # the in-phase slope at this amplitude
            rest = self.current_for(j, frequency_hz) - (1.0 + lin) * j - tau * derivative(j, frequency_hz)
            lag = 1.0 + lin + 2j * np.pi * frequency_hz * tau * harmonics(i.size)
            j_new = np.fft.irfft(np.fft.rfft(i - rest) / lag, i.size)
            step = float(np.max(np.abs(j_new - j)))
            j = j_new
            if step < _TOL_A:
                return j
        if step > _STALL_A:
            raise CompensatorError(f"rayleigh_loop model: the current-to-flux fixed point did not converge "
                                   f"(last step {step:.3g} A after {_MAX_ITER} passes)")
        return j

    def to_dict(self) -> dict:
        return {"kind": self.kind, "name": self.name, "law": self.law.to_dict(), "terms": list(TERMS),
                "coef": list(self.coef), "report": self.report}

    @classmethod
    def from_dict(cls, d: dict) -> "RayleighLoopModel":
        coef = tuple(map(float, d["coef"]))
        if len(coef) != len(TERMS):
            raise CompensatorError(f"rayleigh_loop model: expected {len(TERMS)} coefficients, got {len(coef)}")
        return cls(StaticLaw.from_dict(d["law"]), coef, dict(d.get("report", {})))


def fit_rayleigh_loop(js: Sequence[np.ndarray], currents: Sequence[np.ndarray], freqs_hz: Sequence[float],
                      weights: Sequence[np.ndarray], law: StaticLaw, names: Sequence[str],
                      through: Sequence[Callable[[np.ndarray], np.ndarray]] | None = None) -> RayleighLoopModel:
    """The coefficients from one period of j and i per recording, each sample weighted (the law's
    slope over the recording's force range) and, with ``through``, put through the force
    instrument: the fit minimises the force error the accuracy counts."""
    if len(js) < 2:
        raise CompensatorError(f"the rayleigh_loop model needs at least 2 recordings, got {len(js)}")
    through = through or [lambda x: x] * len(js)
    a = np.vstack([np.apply_along_axis(h, 0, w[:, None] * _columns(j, f))
                   for j, f, w, h in zip(js, freqs_hz, weights, through)])
    b = np.concatenate([h(w * (i - j)) for j, i, w, h in zip(js, currents, weights, through)])
    fit = linear_fit(a, b)
    coef, se = fit.coef, fit.se
    per = np.split(fit.resid, np.cumsum([j.size for j in js])[:-1])
    report = {"parameters": {t: [float(c), float(s)] for t, c, s in zip(TERMS, coef, se)},
              "max_weighted_residual_pct": {n: 100.0 * float(np.max(np.abs(r))) for n, r in zip(names, per)}}
    return RayleighLoopModel(law, tuple(float(c) for c in coef), report)
