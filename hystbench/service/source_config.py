"""The daemon's configured source, built: every ``[source]`` key that :func:`~.daemon_config.check_source`
let through is honoured here (kind by kind, as its module says), none ignored.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from ..errors import ConfigError
from .daemon_config import DaemonConfig, bench_file_limits

if TYPE_CHECKING:
    from ..acquisition.sources import BenchSource, RigSource, SyntheticSource

__all__ = ["build_source"]

_SIM_KEYS = ("rig", "seed", "effects")


def build_source(cfg: DaemonConfig, *, clear_faults: bool = False) -> RigSource | SyntheticSource | BenchSource:
    """The configured source (``cfg``: a checked :class:`~.daemon_config.DaemonConfig`); the output is off.
    ``clear_faults``: a restart after a fault (latched amplifier faults are cleared, output off)."""
    from ..acquisition.sources import RigSource, SyntheticSource, bench_source

    s = cfg["source"]
    if s["kind"] == "synthetic":
        return SyntheticSource(fs_hz=s["fs_hz"], frequency_hz=s["frequency_hz"], block_samples=s["block_samples"],
                               pace=s["pace"], rig=s["rig"], current_pp_a=s["current_pp_a"], seed=s["seed"])
    if s["kind"] == "bench":
        sim = {k: s[k] for k in _SIM_KEYS if ("source", k) in cfg.given}
        return bench_source(s["bench_file"] or None, rig=s["rig"], sim=sim,
                            excitation=(s["frequency_hz"], s["current_pp_a"]), clear_faults=clear_faults)
    from ..sim_backend.rig import SimulatedRig

    try:
        rig = SimulatedRig(s["rig"], fs_hz=s["fs_hz"], seed=s["seed"], effects=s["effects"] or None,
                           frequency_hz=s["frequency_hz"], current_pp_a=s["current_pp_a"])
    except ConfigError as err:
        raise ConfigError(f"{cfg.source} [source]: {err}") from None
    rig.output_enabled = False  # nothing is driven until a sweep or a command says so
    return RigSource(rig, block_samples=s["block_samples"], pace=s["pace"],
                     max_current_a=bench_file_limits().max_current_a)
