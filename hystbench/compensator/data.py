"""What the models are fitted on and judged against: one operating point as period averages.

:func:`.sweeps.period_data` builds these from recordings (the method's delays give the true
frequency and theta_hyst; the synchronous average gives the waveforms), so the models need nothing
of recordings or estimators.  All channels of a point share phase 0 (the same instant).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["PeriodData"]


@dataclass(frozen=True)
class PeriodData:
    """Period-averaged current (A), flux (Wb, AC only) and measured force (N) of one recording."""

    name: str
    frequency_hz: float  # estimated true excitation frequency
    nominal_frequency_hz: float
    current_pp_a: float  # nominal peak-to-peak
    current_a: np.ndarray
    flux_wb: np.ndarray
    force_n: np.ndarray
    theta_hyst_rad: float = math.nan  # flux behind current (the method), for the paper's Eq. 6
    theta_hyst_se_rad: float = math.nan
    force_noise_rms_n: float = math.nan  # one period's noise about the average (per sample)
    periods: int = 0
    current_noise_rms_a: float = math.nan  # the same for the current

    def __post_init__(self) -> None:
        sizes = {np.size(self.current_a), np.size(self.flux_wb), np.size(self.force_n)}
        if len(sizes) != 1 or min(sizes) < 16:
            raise ValueError(f"{self.name}: current, flux and force must be periods of one length >= 16, "
                             f"got {sorted(sizes)}")

    @property
    def n(self) -> int:
        return int(np.size(self.current_a))

    @property
    def force_range_n(self) -> float:
        return float(np.ptp(self.force_n))

    def average_noise_a(self) -> float:
        """Noise of one point of the averaged current (A): a sample's noise over sqrt(periods)."""
        if not (self.periods > 0 and np.isfinite(self.current_noise_rms_a)):
            return math.nan
        return float(self.current_noise_rms_a / np.sqrt(self.periods))
