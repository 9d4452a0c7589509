"""The voice coil: Lorentz force, optionally lagged by the magnet's eddy currents."""

from __future__ import annotations

from typing import Any, Mapping

import numpy as np
from scipy import signal

from ...physics.instrument import bilinear_sos
from ...physics.presets import voice_coil
from .base import ActuatorOutput

__all__ = ["VoiceCoilActuator"]


class VoiceCoilActuator:
    """Lorentz force, lagged by the magnet's eddy currents when that effect is on."""

    has_force = True
    has_flux = False
    sets_current = False

    def __init__(self, preset: Mapping[str, Any], effects: Mapping[str, Mapping[str, Any]], fs_hz: float):
        self.model = voice_coil(preset)
        self._sos = None
        if "magnet_eddy_currents" in effects and self.model.eddy_time_constant_s > 0:
            self._sos = bilinear_sos(*self.model.eddy_lag_sections(), fs_hz)
            self._zi = None

    def dc_flux_wb(self, current_a: float) -> float:
        return 0.0

    def step(self, t_s: np.ndarray, current_a: np.ndarray, dcurrent_dt: np.ndarray) -> ActuatorOutput:
        force = self.model.force(current_a)
        if self._sos is not None:
            if self._zi is None:
                self._zi = signal.sosfilt_zi(self._sos) * force[0]
            force, self._zi = signal.sosfilt(self._sos, force, zi=self._zi)
        return ActuatorOutput(force, None, None)
