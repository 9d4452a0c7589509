"""The iron's loop follows its temperature: a temperature coefficient of its static field.

A soft ferrite's or steel's coercivity and permeability move with temperature: below their loss
minimum MnZn ferrites need less field for the same flux density as they warm (their hysteresis loss
per cycle falls by roughly 0.3-1 %/K up to 80-100 degC, the vendors' loss-against-temperature curves),
and an electrical steel's loop narrows more slowly.  To first order the static field at a flux
density scales,

    H_static(B, T) = H_static(B, T_0) (1 + a_T (T - T_0)),

a_T the loop's temperature coefficient (1/K).  On a bench the coil's losses warm the iron along the
day, T - T_0 = (dT/dt) t, so the iron's reluctivity and its hysteresis delay follow the day's clock
(the magnet's remanence does too: ``magnet_thermal_drift``).  The rise is bounded (``max_rise_k``):
the loop never reverses, and a long day levels off instead of running away.  The eddy-current and
rate fields keep their own coefficients (their conductivity's dependence is another effect).
"""

from __future__ import annotations

from typing import Any, Mapping

import numpy as np

__all__ = ["IronThermal", "iron_thermal"]


class IronThermal:
    """The static field's scale along the day's clock for one iron (``iron_thermal_drift``)."""

    def __init__(self, kelvin_per_s: float, field_tc_per_k: float, max_rise_k: float) -> None:
        self.kelvin_per_s = float(kelvin_per_s)
        self.field_tc_per_k = float(field_tc_per_k)
        self.max_rise_k = float(max_rise_k)

    def scale(self, t_s: np.ndarray) -> np.ndarray:
        """1 + a_T (T - T_0) at the times ``t_s`` (s on the day's clock, the warming from t = 0)."""
        rise = np.clip(self.kelvin_per_s * np.asarray(t_s, dtype=float), -self.max_rise_k, self.max_rise_k)
        return 1.0 + self.field_tc_per_k * rise


def iron_thermal(effects: Mapping[str, Mapping[str, Any]]) -> IronThermal | None:
    """The scale ``iron_thermal_drift`` switches on (None: off)."""
    p = effects.get("iron_thermal_drift")
    return None if p is None else IronThermal(p["kelvin_per_s"], p["field_tc_per_k"], p["max_rise_k"])
