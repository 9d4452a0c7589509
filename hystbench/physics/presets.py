"""Physics models built from a rig preset (a dict loaded by ``hystbench.config``).

The simulator, the estimators and the compensator all build their models here, so a preset means
the same actuator everywhere.  Messages name the preset file and the table/key at fault.
"""

from __future__ import annotations

import math
from typing import Any, Mapping

from ..config import require
from ..errors import ConfigError
from .instrument import InstrumentModel
from .mec import ECoreGeometry, ECoreMEC, Magnet
from .voice_coil import VoiceCoil

__all__ = ["ecore_mec", "voice_coil", "instrument", "where"]


def where(preset: Mapping[str, Any], table: str | None = None) -> str:
    """'path/to/preset.toml [table]': the place a message should name."""
    base = str(preset.get("_source", preset.get("name", "preset")))
    return base if table is None else f"{base} [{table}]"


def ecore_mec(preset: Mapping[str, Any], *, linear_iron: bool = False) -> ECoreMEC:
    """The E-core's MEC from a rig preset; ``linear_iron`` gives the paper's non-hysteretic
    analytical model with the preset's iron (``linear_mu_r``, and ``incremental_mu_r`` when the
    iron is linearised at its operating point), otherwise iron is ideal."""
    geo_t = preset.get("geometry")
    if not isinstance(geo_t, dict):
        raise ConfigError(f"{where(preset)}: missing table [geometry]")
    geo = ECoreGeometry(
        **{k: float(require(geo_t, k, where(preset, "geometry"))) for k in (
            "outer_tooth_width_m", "middle_tooth_width_m", "depth_m", "slot_width_m",
            "slot_height_m", "airgap_m", "iron_path_length_m", "middle_tooth_recess_m")},
        fringe_height_m=float(geo_t.get("fringe_height_m", 0.0)),
        coil_turns=int(require(preset.get("coil", {}), "turns", where(preset, "coil"), int)),
    )
    magnet = None
    if "magnet" in preset:
        m = preset["magnet"]
        magnet = Magnet(
            length_m=float(require(m, "length_m", where(preset, "magnet"))),
            remanence_t=float(require(m, "remanence_t", where(preset, "magnet"))),
            recoil_mu_r=float(m.get("recoil_mu_r", 1.05)),
            conductivity_s_per_m=float(m.get("conductivity_s_per_m", 0.0)),
        )
    mu_r, mu_inc = math.inf, None
    if linear_iron:
        iron = preset.get("iron", {})
        mu_r = float(require(iron, "linear_mu_r", where(preset, "iron")))
        if "incremental_mu_r" in iron:
            mu_inc = float(require(iron, "incremental_mu_r", where(preset, "iron")))
    return ECoreMEC(geo, magnet, iron_mu_r=mu_r, iron_incremental_mu_r=mu_inc)


def voice_coil(preset: Mapping[str, Any]) -> VoiceCoil:
    vc = preset.get("voicecoil", {})
    w = where(preset, "voicecoil")
    return VoiceCoil(
        float(require(vc, "force_constant_n_per_a", w)),
        float(vc.get("magnet_conductivity_s_per_m", 0.0)),
        float(vc.get("magnet_eddy_depth_m", 0.0)),
    )


def instrument(preset: Mapping[str, Any]) -> InstrumentModel:
    """The paper's two-filter instrument model with the preset's parameters."""
    t = preset.get("instrument")
    if not isinstance(t, dict):
        raise ConfigError(f"{where(preset)}: missing table [instrument]")
    w = where(preset, "instrument")
    return InstrumentModel(fn_hz=float(require(t, "fn_hz", w)), zeta_n=float(require(t, "zeta_n", w)),
                           f0_hz=float(require(t, "f0_hz", w)), zeta_0=float(require(t, "zeta_0", w)))
