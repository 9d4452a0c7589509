"""Each rig preset at its operating point, beside the paper's figures (``hystbench rigs``).

The force range is the static analytical model's (the paper's Eq. 1 with the preset's linear iron)
over one period of the preset's sine excitation; the simulated rig lands within a few tenths of a
percent of it (see tests/sim_backend/test_operating_points.py).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from ..config import load_rig, rig_names
from ..formats.recording import with_point
from ..messages import OperatingPoint
from ..physics import presets

__all__ = ["PAPER_FORCE_RANGES_N", "operating_points", "static_force_range"]

#: (min, max, where in the paper): the operating points the presets must reproduce.
PAPER_FORCE_RANGES_N: dict[str, tuple[float, float, str]] = {
    "ecore": (0.0, 3.3, "0-3.3 N at 1.27 A-pp (Sec. VI)"),
    "ecore_pm": (125.0, 220.0, "125-220 N at 1.4 A-pp (Sec. VI)"),
}


def static_force_range(preset: dict[str, Any], current_pp_a: float, offset_a: float = 0.0) -> tuple[float, float]:
    """(min, max) of the static force over a sine of ``current_pp_a`` around ``offset_a``."""
    i = offset_a + 0.5 * current_pp_a * np.sin(np.linspace(0, 2 * np.pi, 2001))
    if preset["actuator"] == "ecore":
        f = presets.ecore_mec(preset, linear_iron=True).force(i)
    elif preset["actuator"] == "voicecoil":
        f = presets.voice_coil(preset).force(i)
    else:
        raise ValueError(f"{presets.where(preset)}: a {preset['actuator']} has no force")
    return float(f.min()), float(f.max())


def operating_points() -> list[dict[str, Any]]:
    """One row per rig preset (``hystbench rigs``): rig, actuator, its operating point in the
    recording sidecar's spelling (written by :func:`~hystbench.formats.recording.with_point`, read
    back by ``sidecar_point``), the static force range and the paper's, where it gives one."""
    rows = []
    for name in rig_names():
        preset = load_rig(name)
        exc = preset["excitation"]  # the preset schema fills it in
        point = OperatingPoint(exc["frequency_hz"], exc["current_pp_a"], offset_a=math.nan)  # NaN: a preset has none
        row = with_point({"rig": name, "actuator": preset["actuator"]}, point)
        if preset["actuator"] in ("ecore", "voicecoil"):
            row["force_min_N"], row["force_max_N"] = static_force_range(preset, point.current_pp_a)
        if name in PAPER_FORCE_RANGES_N:
            row["paper"] = PAPER_FORCE_RANGES_N[name][2]
        rows.append(row)
    return rows
