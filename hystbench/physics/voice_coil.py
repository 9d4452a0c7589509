"""Voice-coil actuator: Lorentz force F = Bl i, optionally delayed by eddy currents in its magnet.

Used to identify the force-measurement instrument (paper Sec. IV): with a ferrite magnet
(rho = 1-100 Ohm m) the actuator adds no phase, so the measured phase is the instrument's.  NdFeB and
SmCo conduct, and their eddy currents lag the force (about 15 deg at 3 kHz, Fig. 7c); modelled as
the slab's low-frequency first-order lag tau = mu0 sigma d^2/12.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from .eddy import slab_time_constant

__all__ = ["VoiceCoil"]


@dataclass(frozen=True)
class VoiceCoil:
    """The voice coil of the module docstring: a force with no hysteresis, to identify the instrument."""

    force_constant_n_per_a: float
    magnet_conductivity_s_per_m: float = 0.0
    magnet_eddy_depth_m: float = 0.0

    @property
    def eddy_time_constant_s(self) -> float:
        """tau of the magnet's eddy lag (s); 0 for a ferrite (non-conducting) magnet."""
        return slab_time_constant(self.magnet_conductivity_s_per_m, self.magnet_eddy_depth_m)

    def force(self, current_a: ArrayLike) -> np.ndarray:
        """Static force (N): no eddy lag."""
        return self.force_constant_n_per_a * np.asarray(current_a, dtype=float)

    def frequency_response(self, frequency_hz: ArrayLike, *, eddy: bool = True) -> complex | np.ndarray:
        """Complex force per ampere; ``eddy`` switches the magnet's eddy lag."""
        w = 2 * np.pi * np.asarray(frequency_hz, dtype=float)
        tau = self.eddy_time_constant_s if eddy else 0.0
        return self.force_constant_n_per_a / (1.0 + 1j * w * tau)

    def eddy_lag_sections(self) -> tuple[np.ndarray, np.ndarray]:
        """(b, a) of 1/(1 + s tau), the continuous lag, for discretisation by the simulator."""
        return np.array([1.0]), np.array([self.eddy_time_constant_s, 1.0])
