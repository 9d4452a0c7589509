"""Physics models built from a rig preset (a dict loaded and checked by ``hystbench.config.load_rig``).

The simulator, the estimators and the compensator all build their models here, so a preset means
the same actuator everywhere.  The preset's keys were checked when it was loaded (types, units,
ranges, the tables its actuator needs), so the values are read here as they are; asking an
actuator's model of a preset of another kind is refused naming the preset.
"""

from __future__ import annotations

from typing import Any, Mapping

from ..errors import ConfigError
from .instrument import InstrumentModel
from .mec import ECoreGeometry, ECoreMEC, Magnet
from .voice_coil import VoiceCoil

__all__ = ["ecore_mec", "voice_coil", "instrument", "where"]


def where(preset: Mapping[str, Any], table: str | None = None) -> str:
    """'path/to/preset.toml [table]': the place a message should name."""
    base = str(preset.get("_source", preset.get("name", "preset")))
    return base if table is None else f"{base} [{table}]"


def _table(preset: Mapping[str, Any], table: str) -> Mapping[str, Any]:
    t = preset.get(table)
    if not isinstance(t, Mapping):
        raise ConfigError(f"{where(preset)}: missing table [{table}] (actuator {preset.get('actuator')!r})")
    return t


def ecore_mec(preset: Mapping[str, Any], *, linear_iron: bool = False) -> ECoreMEC:
    """The E-core's MEC from a rig preset; ``linear_iron`` gives the paper's non-hysteretic
    analytical model with the preset's iron (``linear_mu_r``, and ``incremental_mu_r`` when the
    iron is linearised at its operating point), otherwise iron is ideal."""
    geo = ECoreGeometry(**_table(preset, "geometry"), coil_turns=_table(preset, "coil")["turns"])
    m = preset.get("magnet")
    magnet = None if m is None else Magnet(m["length_m"], m["remanence_t"], m["recoil_mu_r"],
                                           m["conductivity_s_per_m"])
    mu_r, mu_inc = float("inf"), None
    if linear_iron:
        iron = _table(preset, "iron")
        mu_r, mu_inc = iron["linear_mu_r"], iron.get("incremental_mu_r")
    return ECoreMEC(geo, magnet, iron_mu_r=mu_r, iron_incremental_mu_r=mu_inc)


def voice_coil(preset: Mapping[str, Any]) -> VoiceCoil:
    """The voice coil of a rig preset: the actuator that identifies the force instrument (paper Sec. IV)."""
    vc = _table(preset, "voicecoil")
    return VoiceCoil(vc["force_constant_n_per_a"], vc["magnet_conductivity_s_per_m"], vc["magnet_eddy_depth_m"])


def instrument(preset: Mapping[str, Any]) -> InstrumentModel:
    """The paper's two-filter instrument model with the preset's parameters."""
    t = _table(preset, "instrument")
    return InstrumentModel(fn_hz=t["fn_hz"], zeta_n=t["zeta_n"], f0_hz=t["f0_hz"], zeta_0=t["zeta_0"])
