"""What every description of the best model shares: the force is the static law of the current the
airgaps see, j, and a description of the iron maps the coil current to j and back."""

from __future__ import annotations

import numpy as np

from .static import StaticLaw

__all__ = ["SeenCurrentModel"]


class SeenCurrentModel:
    """Base of the best model's iron descriptions: they give ``effective_current`` (i -> j) and
    ``current_for`` (j -> i); the force, the feed-forward and theta_hyst follow here."""

    law: StaticLaw

    def effective_current(self, current_a: np.ndarray, frequency_hz: float) -> np.ndarray:
        raise NotImplementedError

    def current_for(self, j_a: np.ndarray, frequency_hz: float) -> np.ndarray:
        raise NotImplementedError

    def force_period(self, current_a: np.ndarray, frequency_hz: float) -> np.ndarray:
        """The actuator's force (N) over one period of the coil current."""
        return self.law.force(self.effective_current(current_a, frequency_hz))

    def current_period(self, force_n: np.ndarray, frequency_hz: float,
                       current_limit_a: float | None = None) -> np.ndarray:
        """The coil current (one period) that makes the actuator produce ``force_n``."""
        return self.current_for(self.law.invert(force_n, current_limit_a=current_limit_a), frequency_hz)

    def flux_lag_rad(self, current_a: np.ndarray, frequency_hz: float) -> float:
        """The model's theta_hyst: phase of j's fundamental behind the current's (what the method
        measures as flux behind current)."""
        j = self.effective_current(current_a, frequency_hz)
        return float(np.angle(np.fft.rfft(current_a)[1] / np.fft.rfft(j)[1]))
