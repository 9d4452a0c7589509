"""The phase-delay hysteresis model of the paper's Eq. 6: the non-hysteretic force (Eq. 1) with the
current delayed by an equivalent phase theta_hyst(f).

    F(t) = k0 + k1 i(w t - theta_hyst) + k2 i(w t - theta_hyst)^2          (Eq. 6)

with (k0, k1, k2) the MEC's force coefficients at the airgap (Eq. 1: k2 = N1/2 dphi_coil/dz,
k1 = N1 dphi_pm/dz, k0 = Hc lpm/2 dphi_pm/dz, signs as in :meth:`ECoreMEC.force_coefficients`).
theta_hyst is measured per excitation frequency (flux behind current, paper Secs. III and VII) and
interpolated between the measured frequencies.  It is a steady-state AC model: a periodic current
at one fundamental frequency, delayed as a whole by theta_hyst(f) / (2 pi f) seconds; it has no
rate dependence within a period (the paper: "not applicable for arbitrary input signals").

Arrays in, arrays out; SI units (rad, s, Hz, A, N).  The compensator (issue 6) inverts it.

>>> import numpy as np
>>> m = PhaseDelayModel.from_phases((150.0, 60.0, 5.0), [40.0, 320.0], [0.005, 0.02])
>>> float(m.theta(180.0))
0.0125
>>> i = 0.7 * np.sin(2 * np.pi * np.arange(8) / 8)
>>> bool(np.allclose(PhaseDelayModel.non_hysteretic((150.0, 60.0, 5.0)).force_period(i, 320.0),
...                  150.0 + 60.0 * i + 5.0 * i**2))
True
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, SupportsFloat

import numpy as np
from numpy.typing import ArrayLike
from scipy.interpolate import CubicSpline

if TYPE_CHECKING:
    from .mec import ECoreMEC

__all__ = ["PhaseDelayModel", "delay_periodic", "delay_record"]


def _as_1d(x, name: str) -> np.ndarray:
    arr = np.atleast_1d(np.asarray(x, dtype=float))
    if arr.ndim != 1:
        raise ValueError(f"{name} must be 1-D, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite")
    return arr


def delay_periodic(x: ArrayLike, delay_periods: float) -> np.ndarray:
    """One period of a periodic signal, uniformly sampled, delayed by ``delay_periods`` of a period
    (a fraction; positive = later).  Exact for a band-limited signal (phase shift of every DFT bin).

    >>> import numpy as np
    >>> x = np.cos(2 * np.pi * np.arange(16) / 16)
    >>> bool(np.allclose(delay_periodic(x, 0.25), np.sin(2 * np.pi * np.arange(16) / 16)))
    True
    """
    x = _as_1d(x, "x")
    n = x.size
    spec = np.fft.rfft(x)
    shifted = spec * np.exp(-2j * np.pi * np.arange(spec.size) * float(delay_periods))
    if n % 2 == 0:  # the Nyquist bin of a real signal stays real: only its cosine part survives
        shifted[-1] = spec[-1].real * np.cos(np.pi * n * float(delay_periods))
    return np.fft.irfft(shifted, n)


def delay_record(x: ArrayLike, fs_hz: float, delay_s: float, frequency_hz: float) -> np.ndarray:
    """A sampled steady-state periodic record (fundamental ``frequency_hz``) delayed by ``delay_s``
    (cubic interpolation).  The first samples, which would need times before the record, take the
    value one period later (the signal is periodic), so the record must span one period + delay."""
    x = _as_1d(x, "x")
    if not fs_hz > 0 or not frequency_hz > 0:
        raise ValueError(f"fs_hz and frequency_hz must be > 0, got {fs_hz!r}, {frequency_hz!r}")
    t = np.arange(x.size) / fs_hz
    period = 1.0 / frequency_hz
    span = t[-1] if x.size > 1 else 0.0
    td = t - delay_s
    td = np.where(td < 0.0, td + period * np.ceil(-td / period), td)
    td = np.where(td > span, td - period * np.ceil((td - span) / period), td)
    if np.any(td < 0.0) or np.any(td > span):
        raise ValueError(f"x spans {span:g} s: too short for one period ({period:g} s) plus the delay "
                         f"({delay_s:g} s)")
    return CubicSpline(t, x)(td)


@dataclass(frozen=True)
class PhaseDelayModel:
    """Eq. 6: force coefficients (k0, k1, k2) and theta_hyst measured at ``frequency_hz``.

    ``theta(f)`` is piecewise linear through the measured points; below the lowest measured
    frequency it is held (a rate-independent hysteresis loop keeps its phase as f -> 0); above
    the highest it continues along the last segment (the eddy-current part grows with f).  With
    one point, theta is that constant.  Several points at one frequency (e.g. several amplitudes;
    the paper finds theta independent of amplitude when the iron is not saturated) are averaged,
    inverse-variance weighted when standard errors are given.
    """

    k0_n: float
    k1_n_per_a: float
    k2_n_per_a2: float
    frequency_hz: np.ndarray = field(default_factory=lambda: np.zeros(0))
    theta_rad: np.ndarray = field(default_factory=lambda: np.zeros(0))
    theta_se_rad: np.ndarray | None = None

    # --- construction --------------------------------------------------------------------------
    @classmethod
    def non_hysteretic(cls, coefficients: Sequence[SupportsFloat]) -> PhaseDelayModel:
        """theta = 0 at every frequency: the paper's Eq. 1."""
        k0, k1, k2 = (float(c) for c in coefficients)
        return cls(k0, k1, k2, np.array([1.0]), np.array([0.0]), np.array([0.0]))

    @classmethod
    def from_phases(cls, coefficients: Sequence[SupportsFloat], frequency_hz: ArrayLike, theta_rad: ArrayLike,
                    theta_se_rad: ArrayLike | None = None) -> PhaseDelayModel:
        """From per-point phase delays theta_hyst (rad, positive: the force lags) at ``frequency_hz``."""
        f = _as_1d(frequency_hz, "frequency_hz")
        th = _as_1d(theta_rad, "theta_rad")
        if f.size == 0 or f.size != th.size:
            raise ValueError("frequency_hz and theta_rad must be non-empty and of one length, "
                             f"got {f.size}, {th.size}")
        if np.any(f <= 0):
            raise ValueError("frequency_hz must be > 0")
        se = None if theta_se_rad is None else _as_1d(theta_se_rad, "theta_se_rad")
        if se is not None and (se.size != f.size or np.any(se < 0)):
            raise ValueError("theta_se_rad must be >= 0 and as long as frequency_hz")
        grid = np.unique(f)
        th_g, se_g = np.empty(grid.size), np.empty(grid.size)
        for j, fj in enumerate(grid):
            sel = f == fj
            if se is not None and np.all(se[sel] > 0):
                w = 1.0 / se[sel] ** 2
                th_g[j], se_g[j] = np.sum(w * th[sel]) / np.sum(w), 1.0 / np.sqrt(np.sum(w))
            else:
                th_g[j] = th[sel].mean()
                se_g[j] = np.nan if se is None else float(np.sqrt(np.sum(se[sel] ** 2))) / sel.sum()
        k0, k1, k2 = (float(c) for c in coefficients)
        return cls(k0, k1, k2, grid, th_g, None if se is None else se_g)

    @classmethod
    def from_delays(cls, coefficients: Sequence[SupportsFloat], frequency_hz: ArrayLike, delay_s: ArrayLike,
                    delay_se_s: ArrayLike | None = None) -> PhaseDelayModel:
        """From per-point time delays of the flux behind the current (s) at ``frequency_hz``."""
        f = _as_1d(frequency_hz, "frequency_hz")
        w = 2 * np.pi * f
        se = None if delay_se_s is None else w * _as_1d(delay_se_s, "delay_se_s")
        return cls.from_phases(coefficients, f, w * _as_1d(delay_s, "delay_s"), se)

    @classmethod
    def from_mec(cls, mec: ECoreMEC, frequency_hz: ArrayLike, theta_rad: ArrayLike,
                 theta_se_rad: ArrayLike | None = None, airgap_m: float | None = None) -> PhaseDelayModel:
        """Coefficients from an :class:`~hystbench.physics.mec.ECoreMEC` at ``airgap_m`` (default:
        its nominal airgap), theta as in :meth:`from_phases`."""
        z = mec.geometry.airgap_m if airgap_m is None else airgap_m
        return cls.from_phases(mec.force_coefficients(z), frequency_hz, theta_rad, theta_se_rad)

    # --- the model -----------------------------------------------------------------------------
    @property
    def coefficients(self) -> tuple[float, float, float]:
        return self.k0_n, self.k1_n_per_a, self.k2_n_per_a2

    def theta(self, frequency_hz: ArrayLike) -> float | np.ndarray:
        """theta_hyst (rad) at ``frequency_hz`` (array or scalar)."""
        f = np.asarray(frequency_hz, dtype=float)
        grid, th = self.frequency_hz, self.theta_rad
        if grid.size == 1:
            return np.full(f.shape, th[0])[()]
        out = np.interp(f, grid, th)  # holds th[0] below grid[0]
        slope = (th[-1] - th[-2]) / (grid[-1] - grid[-2])
        return np.where(f > grid[-1], th[-1] + slope * (f - grid[-1]), out)[()]

    def delay_s(self, frequency_hz: ArrayLike) -> float | np.ndarray:
        """theta_hyst as the equivalent time delay of the current (s)."""
        f = np.asarray(frequency_hz, dtype=float)
        return self.theta(f) / (2 * np.pi * f)

    def static_force(self, current_a: ArrayLike) -> np.ndarray:
        """Eq. 1: k0 + k1 i + k2 i^2 (N)."""
        i = np.asarray(current_a, dtype=float)
        return self.k0_n + self.k1_n_per_a * i + self.k2_n_per_a2 * i * i

    def force_period(self, current_a: ArrayLike, frequency_hz: float) -> np.ndarray:
        """Eq. 6 for one period of a periodic current (uniformly sampled, the compensator's table):
        the table is delayed by theta(f) / 2 pi of a period, then put through Eq. 1."""
        th = float(self.theta(float(frequency_hz)))
        return self.static_force(delay_periodic(current_a, th / (2 * np.pi)))

    def force(self, current_a: ArrayLike, fs_hz: float, frequency_hz: float) -> np.ndarray:
        """Eq. 6 for a sampled steady-state record of a periodic current at ``frequency_hz``."""
        d = float(self.delay_s(float(frequency_hz)))
        return self.static_force(delay_record(current_a, fs_hz, d, frequency_hz))

    def force_sine(self, t_s: ArrayLike, amplitude_a: float, frequency_hz: float, offset_a: float = 0.0,
                   phase_rad: float = 0.0) -> np.ndarray:
        """Eq. 6 for i(t) = offset + amplitude sin(2 pi f t + phase), in closed form."""
        t = np.asarray(t_s, dtype=float)
        arg = 2 * np.pi * frequency_hz * t + phase_rad - float(self.theta(frequency_hz))
        return self.static_force(offset_a + amplitude_a * np.sin(arg))
