"""Truth physics of the actuators on the bench (``base`` holds the interface they share).

- :class:`ECoreActuator` (``ecore``), :class:`VoiceCoilActuator` (``voice_coil``),
  :class:`ToroidCore` (``toroid``: the paper's IEC 60404-4 ring, flux-controlled);
- :func:`build_actuator` picks one by the preset's ``actuator`` key.
"""

from __future__ import annotations

from typing import Any, Mapping

from ...errors import ConfigError
from ...physics.presets import where as preset_where
from .base import Actuator, ActuatorOutput
from .ecore import IRON_ITERATIONS, ECoreActuator
from .toroid import ToroidCore
from .voice_coil import VoiceCoilActuator

__all__ = ["ActuatorOutput", "Actuator", "ECoreActuator", "VoiceCoilActuator", "ToroidCore",
           "build_actuator", "ACTUATORS", "IRON_ITERATIONS"]

#: The preset's ``actuator`` key -> the class that simulates it.
ACTUATORS = {"ecore": ECoreActuator, "voicecoil": VoiceCoilActuator, "toroid": ToroidCore}


def build_actuator(preset: Mapping[str, Any], effects: Mapping[str, Mapping[str, Any]], fs_hz: float) -> Actuator:
    """The preset's actuator, by its ``actuator`` key: the rig runs any of them through one interface."""
    kind = preset.get("actuator")
    if kind not in ACTUATORS:
        raise ConfigError(f"{preset_where(preset)}: unknown actuator {kind!r}; "
                          f"known: {', '.join(ACTUATORS)}")
    return ACTUATORS[kind](preset, effects, fs_hz)
