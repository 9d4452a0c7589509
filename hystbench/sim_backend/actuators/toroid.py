"""The laminated toroid of the paper's Fig. 4, measured the IEC 60404-4 way.

The standard asks for a sinusoidal flux density, so the amplifier runs in flux feedback: the
generator's command sets B (``[amplifier] flux_density_per_a_t`` tesla per ampere of nominal
command), and the magnetising current needed for it is what the current channel measures,
i = (H_static(B) + sigma d^2/12 dB/dt) l / N.  Driving the B-input hysteresis operator this way
is also exact: no implicit solve is needed with eddy currents.
"""

from __future__ import annotations

from typing import Any, Mapping

import numpy as np

from ...config import load_material, require
from ...physics.eddy import lamination_eddy_coefficient
from ...physics.presets import where
from .base import ActuatorOutput

__all__ = ["ToroidCore"]


class ToroidCore:
    has_force = False
    has_flux = True

    def __init__(self, preset: Mapping[str, Any], effects: Mapping[str, Mapping[str, Any]], fs_hz: float):
        from ...physics.hysteresis import PreisachHysteresis

        ring = preset.get("toroid", {})
        r_in = float(require(ring, "inner_radius_m", where(preset, "toroid")))
        r_out = float(require(ring, "outer_radius_m", where(preset, "toroid")))
        height = float(require(ring, "height_m", where(preset, "toroid")))
        self.area_m2 = (r_out - r_in) * height
        self.path_m = np.pi * (r_in + r_out)  # mean magnetic path
        self.turns = int(require(preset.get("coil", {}), "turns", where(preset, "coil"), int))
        self.tesla_per_a = float(require(preset.get("amplifier", {}), "flux_density_per_a_t",
                                         where(preset, "amplifier")))
        iron = preset.get("iron", {})
        self.hysteresis = PreisachHysteresis.from_config(
            load_material(require(iron, "material", where(preset, "iron"), str)))
        self._state = self.hysteresis.initial_state()
        self._irreversible = "static_hysteresis" in effects
        self._saturation = "iron_saturation" in effects
        self._eddy = 0.0
        if "lamination_eddy_currents" in effects:
            self._eddy = lamination_eddy_coefficient(
                float(require(iron, "conductivity_s_per_m", where(preset, "iron"))),
                float(require(iron, "lamination_thickness_m", where(preset, "iron"))))

    def dc_flux_wb(self, current_a: float) -> float:
        return self.tesla_per_a * current_a * self.area_m2

    def step(self, t_s, current_a, dcurrent_dt) -> ActuatorOutput:
        b = self.tesla_per_a * current_a  # the flux-feedback reference, followed exactly
        db_dt = self.tesla_per_a * dcurrent_dt
        h, self._state = self.hysteresis.field(b, self._state, irreversible=self._irreversible,
                                               saturation=self._saturation)
        h = h + self._eddy * db_dt
        return ActuatorOutput(None, b * self.area_m2, db_dt * self.area_m2,
                              current_a=h * self.path_m / self.turns)
