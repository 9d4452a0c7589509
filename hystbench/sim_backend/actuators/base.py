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
    """One block of an actuator's truth, before any instrument sees it; None: it has no such output."""

    force_n: np.ndarray | None  # true force on the load cell
    flux_wb: np.ndarray | None  # true flux through the sense coil (absolute, with any bias)
    dflux_dt: np.ndarray | None  # its time derivative (Wb/s)
    current_a: np.ndarray | None = None  # the coil current, when the actuator sets it (flux control)


class Actuator(Protocol):
    """What the rig asks of an actuator, so an E-core, a toroid and a voice coil are interchangeable."""

    has_force: bool
    has_flux: bool
    #: the actuator sets the coil current itself (flux feedback: the command is a flux density), so
    #: the current it draws is not the command's (SimulatedRig.peak_current_a simulates it)
    sets_current: bool

    def step(self, t_s: np.ndarray, current_a: np.ndarray, dcurrent_dt: np.ndarray) -> ActuatorOutput:
        """The next block (times in s, current in A, dI/dt in A/s); it continues the previous one."""
        ...

    def dc_flux_wb(self, current_a: float) -> float:
        """The flux at a steady current (Wb), which the rig subtracts: the sense coil's integrator sees no DC."""
        ...
