"""The laminated toroid of the paper's Fig. 4, measured the IEC 60404-4 way.

The standard asks for a sinusoidal flux density, so the amplifier runs in flux feedback: the
generator's command sets B (``[amplifier] flux_density_per_a_t`` tesla per ampere of nominal
command), and the magnetising current needed for it is what the current channel measures,
i = (H_static(B) + sigma d^2/12 dB/dt + H_rate) l / N (H_rate: the excess field and the relaxation,
:mod:`hystbench.physics.rate_dependence`; H_static scaled by the iron's temperature with
``iron_thermal_drift``, :mod:`hystbench.physics.iron_thermal`).  Driving the B-input hysteresis
operator this way is also exact: no implicit solve is needed with eddy currents.  The iron is the one
its material file's ``model`` names (:func:`hystbench.physics.iron.iron_model`).
"""

from __future__ import annotations

from typing import Any, Mapping

import numpy as np

from ...config import load_material
from ...physics.eddy import lamination_eddy_coefficient
from ...physics.iron_thermal import iron_thermal
from ...physics.rate_dependence import rate_dependence
from .base import ActuatorOutput

__all__ = ["ToroidCore"]


class ToroidCore:
    """The laminated ring of the module docstring: flux in (B follows the command), current out."""

    has_force = False
    has_flux = True
    sets_current = True

    def __init__(self, preset: Mapping[str, Any], effects: Mapping[str, Mapping[str, Any]], fs_hz: float):
        from ...physics.iron import ComplexPermeabilityIron, iron_model, refuse_saturation

        ring, iron = preset["toroid"], preset["iron"]  # checked by hystbench.config.load_rig
        self.area_m2 = (ring["outer_radius_m"] - ring["inner_radius_m"]) * ring["height_m"]
        self.path_m = np.pi * (ring["inner_radius_m"] + ring["outer_radius_m"])  # mean magnetic path
        self.turns = preset["coil"]["turns"]
        self.tesla_per_a = preset["amplifier"]["flux_density_per_a_t"]
        self.fs_hz = fs_hz
        material = load_material(iron["material"])
        refuse_saturation(material, effects, str(preset.get("_source", preset.get("name"))))
        self.hysteresis = iron_model(material)  # by the material's model (physics.iron)
        #: a complex permeability is linear and rate-dependent: H from B and dB/dt at the excitation's omega
        self._linear = isinstance(self.hysteresis, ComplexPermeabilityIron)
        self._omega = 2.0 * np.pi * float(preset["excitation"]["frequency_hz"])  # until the rig tells the period
        self._state = None if self._linear else self.hysteresis.initial_state()
        self._irreversible = "static_hysteresis" in effects
        self._saturation = "iron_saturation" in effects
        self._eddy = 0.0
        if "lamination_eddy_currents" in effects:
            self._eddy = lamination_eddy_coefficient(iron["conductivity_s_per_m"], iron["lamination_thickness_m"])
        self._rate = rate_dependence(effects, fs_hz)
        self._thermal = iron_thermal(effects)

    def set_period(self, samples: float | None) -> None:
        """The excitation's period in samples: a complex permeability's omega (None: the preset's
        [excitation] frequency stays)."""
        if samples is not None:
            self._omega = 2.0 * np.pi * self.fs_hz / float(samples)

    def dc_flux_wb(self, current_a: float) -> float:
        return self.tesla_per_a * current_a * self.area_m2

    def step(self, t_s: np.ndarray, current_a: np.ndarray, dcurrent_dt: np.ndarray) -> ActuatorOutput:
        b = self.tesla_per_a * current_a  # the flux-feedback reference, followed exactly
        db_dt = self.tesla_per_a * dcurrent_dt
        if self._linear:
            h = self.hysteresis.field(b, db_dt, self._omega, lossy=self._irreversible)
        else:
            h, self._state = self.hysteresis.field(b, self._state, irreversible=self._irreversible,
                                                   saturation=self._saturation)
        if self._thermal is not None:
            h = h * self._thermal.scale(t_s)
        h = h + self._eddy * db_dt
        if self._rate is not None:
            h = h + self._rate.field(b)
            self._rate.commit(b)
        return ActuatorOutput(None, b * self.area_m2, db_dt * self.area_m2,
                              current_a=h * self.path_m / self.turns)
