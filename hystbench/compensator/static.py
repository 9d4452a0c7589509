"""The static force law F = k0 + k1 j + k2 j^2 (the paper's Eq. 1 at a fixed airgap) and its inverse.

``j`` is the current the airgaps see.  Without a magnet (k1 = 0) the force is quadratic and only
attracts: a force reference maps to a unipolar current j = sqrt((F - k0) / k2) (this module
always takes the positive root; a negative force is unreachable).  With a magnet the law is affine
plus quadratic and increasing over the working range j > -k1 / (2 k2) (the flux never reverses),
and the inverse takes the root on that side.  The reachable force for a current limit I follows:
[F(-I), F(I)] with a magnet, [k0, F(I)] without.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import SupportsFloat

import numpy as np
from numpy.typing import ArrayLike

from .errors import UnreachableReference

__all__ = ["StaticLaw"]


def _n(x: float) -> str:
    """A force for a message: 4 digits, and no '-0' for a law whose k0 is zero."""
    return f"{0.0 if abs(x) < 1e-9 else float(x):.4g}"


@dataclass(frozen=True)
class StaticLaw:
    """F(j) = k0 + k1 j + k2 j^2 (N, N/A, N/A^2); ``magnet`` says which inverse applies."""

    k0_n: float
    k1_n_per_a: float
    k2_n_per_a2: float
    magnet: bool

    @classmethod
    def from_coefficients(cls, coefficients: Sequence[SupportsFloat], magnet: bool) -> "StaticLaw":
        """From (k0, k1, k2) as the MEC gives them (:meth:`~hystbench.physics.mec.ECoreMEC.force_coefficients`,
        numpy scalars included), so the law holds plain floats that JSON can write."""
        k0, k1, k2 = (float(c) for c in coefficients)
        return cls(k0, k1, k2, bool(magnet))

    @property
    def coefficients(self) -> tuple[float, float, float]:
        return self.k0_n, self.k1_n_per_a, self.k2_n_per_a2

    def force(self, j_a: ArrayLike) -> np.ndarray:
        """F(j) (N): what the actuator pulls at current ``j_a``, with no delay (the static law)."""
        j = np.asarray(j_a, dtype=float)
        return self.k0_n + self.k1_n_per_a * j + self.k2_n_per_a2 * j * j

    def slope(self, j_a: ArrayLike) -> np.ndarray:
        """dF/dj (N/A)."""
        return self.k1_n_per_a + 2.0 * self.k2_n_per_a2 * np.asarray(j_a, dtype=float)

    @property
    def flux_zero_a(self) -> float:
        """The current where the gap flux is zero (the law's vertex): -k1 / (2 k2)."""
        return -self.k1_n_per_a / (2.0 * self.k2_n_per_a2) if self.k2_n_per_a2 else -np.inf

    def reachable_n(self, current_limit_a: float) -> tuple[float, float]:
        """(min, max) static force for |j| <= current_limit_a."""
        i = float(current_limit_a)
        if not self.magnet:
            return self.k0_n, float(self.force(i))
        lo = max(-i, self.flux_zero_a)
        return float(self.force(lo)), float(self.force(i))

    def invert(self, force_n: ArrayLike, *, current_limit_a: float | None = None) -> np.ndarray:
        """The current j that gives ``force_n`` (see the module docstring for the root taken).

        Raises :class:`UnreachableReference` for a force no current gives (below the law's minimum)
        or, when ``current_limit_a`` is given, one needing |j| above it."""
        f = np.asarray(force_n, dtype=float)
        k0, k1, k2 = self.coefficients
        limit = np.inf if current_limit_a is None else float(current_limit_a)
        span = self.reachable_n(limit) if np.isfinite(limit) else (self._floor_n(), np.inf)
        if not self.magnet and np.any(f < k0):
            raise UnreachableReference(
                f"the reference asks for {_n(f.min())} N, but an E-core without magnet only attracts: "
                f"its force is >= {_n(k0)} N; reachable {_n(span[0])} to {_n(span[1])} N", span)
        if self.magnet and k2 > 0 and np.any(f < self._floor_n()):
            raise UnreachableReference(
                f"the reference asks for {_n(f.min())} N, below the magnet's force at zero gap flux "
                f"({_n(self._floor_n())} N); reachable {_n(span[0])} to {_n(span[1])} N", span)
        if k2 == 0.0:
            j = (f - k0) / k1
        elif not self.magnet:
            j = np.sqrt(np.maximum(f - k0, 0.0) / k2)
        else:  # the root on the side where the flux does not reverse (dF/dj > 0)
            disc = np.maximum(k1 * k1 - 4.0 * k2 * (k0 - f), 0.0)
            j = (-k1 + np.sqrt(disc)) / (2.0 * k2)
        if np.any(np.abs(j) > limit * (1 + 1e-12)):
            raise UnreachableReference(
                f"the reference ({_n(f.min())} to {_n(f.max())} N) needs {float(np.max(np.abs(j))):.4g} A "
                f"static current, above the {limit:g} A limit; reachable {_n(span[0])} to {_n(span[1])} N", span)
        return j

    def _floor_n(self) -> float:
        """The lowest force the law gives at all (its vertex with a magnet, k0 without)."""
        if not self.magnet or self.k2_n_per_a2 <= 0:
            return self.k0_n if not self.magnet else -np.inf
        return float(self.force(self.flux_zero_a))

    def to_dict(self) -> dict:
        return {"k0_N": self.k0_n, "k1_N_per_A": self.k1_n_per_a, "k2_N_per_A2": self.k2_n_per_a2,
                "magnet": self.magnet}

    @classmethod
    def from_dict(cls, d: dict) -> "StaticLaw":
        return cls(float(d["k0_N"]), float(d["k1_N_per_A"]), float(d["k2_N_per_A2"]), bool(d["magnet"]))
