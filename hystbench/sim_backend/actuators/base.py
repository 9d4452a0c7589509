"""What every actuator of the simulated rig gives back, and the interface it keeps.

Each actuator takes the true coil current (and its time derivative, known analytically from the
generator) and returns the true force and the flux through the sense coil.  State (hysteresis
memory, filter states, one previous sample for derivatives) lives in the object, so consecutive
blocks continue each other exactly.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np

__all__ = ["ActuatorOutput", "Actuator"]


@dataclass
class ActuatorOutput:
    force_n: np.ndarray | None  # true force on the load cell
    flux_wb: np.ndarray | None  # true flux through the sense coil (absolute, with any bias)
    dflux_dt: np.ndarray | None  # its time derivative (Wb/s)
    current_a: np.ndarray | None = None  # the coil current, when the actuator sets it (flux control)


class Actuator(Protocol):
    has_force: bool
    has_flux: bool

    def step(self, t_s: np.ndarray, current_a: np.ndarray, dcurrent_dt: np.ndarray) -> ActuatorOutput: ...

    def dc_flux_wb(self, current_a: float) -> float: ...
