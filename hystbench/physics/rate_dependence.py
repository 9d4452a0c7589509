"""The iron's rate dependence beyond classical eddy currents: Bertotti's excess field and a magnetic
relaxation, as extra fields added to the rate-independent H(B) along a sampled trajectory.

Real magnetic materials lose more per cycle than static hysteresis plus the classical eddy field
sigma d^2/12 dB/dt explain, and keep losing after B stops changing (what the flat segments of a
trapezoidal flux reveal).  Two of the field's standard descriptions, each with parameters in
physical units:

- **Excess (domain-wall) field** (G. Bertotti, IEEE Trans. Magn. 24, 621 (1988)): n active magnetic
  objects, n = n0 + H_exc / V0, give

      H_exc = (n0 V0 / 2) (sqrt(1 + 4 sigma G S |dB/dt| / (n0^2 V0)) - 1) sign(dB/dt)
            = k (sqrt(|dB/dt| + r0) - sqrt(r0)) sign(dB/dt),

  k = sqrt(sigma G S V0) (A/m per sqrt(T/s)) and r0 = n0^2 V0 / (4 sigma G S) (T/s): linear below the
  rate r0, k sqrt(|dB/dt|) well above it.  Under a sinusoidal B of peak Bm at frequency f (|dB/dt|
  >> r0) the energy per cycle is C k Bm^1.5 f^0.5 with C = (2 pi)^1.5 <|cos|^1.5> = 8.763
  (:data:`EXCESS_SINE_FACTOR`), Bertotti's excess loss.
- **Magnetic relaxation** (a Debye after-effect): the field holds a share of B's recent change and
  lets it go with a time constant tau,

      H_rel = kappa (B - B_slow),    tau dB_slow/dt = B - B_slow,

  kappa (A/m per T) the reluctivity it adds to fast changes.  Under a sine, H_rel = kappa B
  j w tau / (1 + j w tau): the energy per cycle pi kappa Bm^2 w tau / (1 + (w tau)^2) peaks at
  w tau = 1; far below it the field is kappa tau dB/dt (an eddy-like loss), far above it a
  lossless kappa B; after a ramp stops, H_rel decays as exp(-t / tau).

Both are vectorised over a block and causal: the derivative is the backward difference from the
sample before the block, and B_slow is a first-order recursion (scipy.signal.lfilter) carried over
from block to block, so any cut of the stream into blocks gives the same samples.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Mapping

import numpy as np
from scipy import signal

__all__ = ["EXCESS_SINE_FACTOR", "RateState", "RateDependence", "rate_dependence", "excess_field", "relaxation_field"]

#: Energy per cycle of the excess field under a sine, per k Bm^1.5 f^0.5: (2 pi)^1.5 times the mean of
#: |cos|^1.5 over a period, Gamma(5/4) / (sqrt(pi) Gamma(7/4)).
EXCESS_SINE_FACTOR = (2.0 * math.pi) ** 1.5 * math.gamma(1.25) / (math.sqrt(math.pi) * math.gamma(1.75))


def excess_field(db_dt: np.ndarray, k: float, r0: float) -> np.ndarray:
    """Bertotti's excess field (A/m) at the rates ``db_dt`` (T/s); see the module docstring."""
    rate = np.abs(db_dt)
    return k * np.sign(db_dt) * (np.sqrt(rate + r0) - math.sqrt(r0))


def relaxation_field(b: np.ndarray, b_slow_before: float, tau_s: float, kappa: float, fs_hz: float
                     ) -> tuple[np.ndarray, float]:
    """H_rel (A/m) along b (T) sampled at fs_hz, B_slow starting from ``b_slow_before`` (the sample
    before the block); returns (H_rel, B_slow at the block's last sample).  B_slow[n] = a B_slow[n-1]
    + (1 - a) B[n], a = exp(-1 / (tau fs)): the lag solved exactly over each sample for B at its new
    value."""
    a = math.exp(-1.0 / (tau_s * fs_hz))
    slow, zf = signal.lfilter([1.0 - a], [1.0, -a], b, zi=[a * b_slow_before])
    return kappa * (b - slow), float(zf[0] / a) if a > 0 else float(b[-1]) if b.size else b_slow_before


@dataclass
class RateState:
    """Where the rate terms stand after the last committed sample: B there (the backward difference's
    start) and the relaxation's B_slow.  None before the first block (the iron starts at rest)."""

    b: float
    b_slow: float


class RateDependence:
    """The excess field and the relaxation of one iron, as the E-core adds them to its static H(B):
    ``field(b)`` along a block from the committed state, ``slope(b)`` dH/dB_n for a damped fixed-point
    step, ``commit(b)`` once the block's B is final."""

    def __init__(self, fs_hz: float, excess: tuple[float, float] | None = None,
                 relaxation: tuple[float, float] | None = None) -> None:
        self.fs_hz = float(fs_hz)
        self.excess = excess  # (k in A/m per sqrt(T/s), r0 in T/s)
        self.relaxation = relaxation  # (tau in s, kappa in A/m per T)
        self.state: RateState | None = None

    def _start(self, b: np.ndarray) -> RateState:
        return self.state if self.state is not None else RateState(float(b[0]), float(b[0]))

    def field(self, b: np.ndarray) -> np.ndarray:
        """The rate terms' H (A/m) along the block's B (T), from the committed state."""
        h = np.zeros_like(b)
        if not b.size:
            return h
        st = self._start(b)
        if self.excess is not None:
            h += excess_field(np.diff(b, prepend=st.b) * self.fs_hz, *self.excess)
        if self.relaxation is not None:
            h += relaxation_field(b, st.b_slow, *self.relaxation, self.fs_hz)[0]
        return h

    def slope(self, b: np.ndarray) -> np.ndarray:
        """d H_rate[n] / d B[n] (A/m per T), each sample's own: what damps the fixed point's step where
        the excess field is steep (slow rates, below r0)."""
        s = np.zeros_like(b)
        if not b.size:
            return s
        st = self._start(b)
        if self.excess is not None:
            k, r0 = self.excess
            rate = np.abs(np.diff(b, prepend=st.b)) * self.fs_hz
            s += 0.5 * k * self.fs_hz / np.sqrt(rate + r0)
        if self.relaxation is not None:
            tau, kappa = self.relaxation
            s += kappa * math.exp(-1.0 / (tau * self.fs_hz))
        return s

    def commit(self, b: np.ndarray) -> None:
        """The block's final B: the next block's derivative and B_slow start from its end."""
        if not b.size:
            return
        st = self._start(b)
        b_slow = st.b_slow
        if self.relaxation is not None:
            b_slow = relaxation_field(b, st.b_slow, *self.relaxation, self.fs_hz)[1]
        self.state = RateState(float(b[-1]), b_slow)


def rate_dependence(effects: Mapping[str, Mapping[str, Any]], fs_hz: float) -> RateDependence | None:
    """The rate terms the catalogue's ``excess_loss`` and ``magnetic_relaxation`` switch on (None: neither)."""
    ex, rel = effects.get("excess_loss"), effects.get("magnetic_relaxation")
    if ex is None and rel is None:
        return None
    return RateDependence(
        fs_hz, None if ex is None else (ex["coefficient_a_per_m_per_sqrt_t_per_s"], ex["knee_rate_t_per_s"]),
        None if rel is None else (rel["time_constant_s"], rel["reluctivity_a_per_m_per_t"]))
