"""The daemon's ``[source]`` table, kind by kind: every key is honoured or refused, never ignored.

- ``kind = "bench"``: the bench file's instruments.  Its ``[bench] fs_hz`` and ``[sim]
  block_samples`` / ``pace`` set what ``fs_hz``, ``block_samples`` and ``pace`` would, so those
  are refused when given.  ``rig``, ``seed`` and ``effects`` replace the bench file's ``[sim]``
  ones when it emulates the instruments; with hardware only, ``seed`` and ``effects`` are refused
  (there is no simulation to seed or to switch effects in) and ``rig`` names the recordings.
  ``frequency_hz`` and ``current_pp_a`` set the generator's sine when the bench opens.
- ``kind = "sim"``: the simulated rig directly; ``bench_file`` is refused (nothing reads it).
- ``kind = "synthetic"``: precomputed sines; ``bench_file`` and ``effects`` are refused.

Effects are checked by the effect catalogue (:func:`~hystbench.config.effects.validate_effects`),
the excitation and the sweep against the bench's limits (:mod:`hystbench.acquisition.bench_commands`): a value the
daemon would refuse as a command is refused in its file already.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from ..drivers.protocols.bench_config import load_bench_config
from ..errors import ConfigError
from ..messages import OperatingPoint
from ..acquisition.bench_commands import Limits, check_current, check_frequency

if TYPE_CHECKING:
    from .daemon import DaemonConfig
    from ..acquisition.sources import BenchSource, RigSource, SyntheticSource

__all__ = ["check_source", "build_source", "bench_file_limits"]

_SET_BY_BENCH_FILE = {"fs_hz": "[bench] fs_hz", "block_samples": "[sim] block_samples", "pace": "[sim] pace"}
_SIM_KEYS = ("rig", "seed", "effects")


def bench_file_limits(bench_file: str | None = None) -> Limits:
    """Sample rate and peak current limit of a bench file (None: the shipped one, which also
    stands for the simulated rig: the same amplifier and limits)."""
    cfg = load_bench_config(bench_file or None)
    return Limits(cfg.fs_hz, cfg.current_limit_a)


def _validate_effects(effects: dict, where: str, fs_hz: float) -> None:
    from ..config.effects import validate_effects

    validate_effects(effects, f"{where} [source] effects", fs_hz=fs_hz)


def check_source(values: dict[str, dict[str, Any]], given: set[tuple[str, str]], where: str) -> Limits:
    """Check ``values["source"]`` (and the excitations of ``[sweep]``) for its kind; returns the
    bench's limits.  With an emulated bench and no ``rig`` given, ``rig`` is set to the bench
    file's (so the running configuration says which rig it is)."""
    s = values["source"]
    kind = s["kind"]

    def refuse(k: str, why: str) -> None:
        raise ConfigError(f"{where} [source] {k}: {why}")

    if kind == "bench":
        for k, bench_key in _SET_BY_BENCH_FILE.items():
            if ("source", k) in given:
                refuse(k, f'not used by kind = "bench": the bench file\'s {bench_key} sets it; remove it here')
        bench = load_bench_config(s["bench_file"] or None)
        if bench.any_sim:
            if ("source", "rig") not in given:
                s["rig"] = bench.sim["rig"]
            _validate_effects(s["effects"], where, bench.fs_hz)
        else:
            for k in ("seed", "effects"):
                if ("source", k) in given and (k == "seed" or s[k]):
                    refuse(k, f"applies to the emulated rig, and {bench.source} has hardware instruments only")
        limits = Limits(bench.fs_hz, bench.current_limit_a)
    else:
        if s["bench_file"]:
            refuse("bench_file", f'only kind = "bench" reads a bench file (kind is "{kind}")')
        if kind == "synthetic" and s["effects"]:
            refuse("effects", 'synthetic sines have no physical effects; use kind = "sim" or "bench"')
        if kind == "sim":
            _validate_effects(s["effects"], where, s["fs_hz"])
        from ..acquisition.sources import MAX_BLOCK_SAMPLES

        if s["block_samples"] > MAX_BLOCK_SAMPLES:
            refuse("block_samples", f"must be at most {MAX_BLOCK_SAMPLES:.0e} (a block is computed and held whole), "
                                    f"got {s['block_samples']}")
        limits = Limits(s["fs_hz"], bench_file_limits().max_current_a)
    check_frequency(f"{where} [source] frequency_hz", s["frequency_hz"], limits)
    check_current(f"{where} [source]", OperatingPoint(s["frequency_hz"], s["current_pp_a"]), limits)
    if kind != "synthetic":  # a synthetic source takes no commands, so it runs no sweep
        sw = values["sweep"]
        for k, f in enumerate(sw["frequencies_hz"]):
            check_frequency(f"{where} [sweep] frequencies_hz[{k}]", f, limits)
        check_current(f"{where} [sweep]", OperatingPoint(sw["frequencies_hz"][0], sw["current_pp_a"]), limits)
    elif values["sweep"]["autostart"]:
        raise ConfigError(f'{where} [sweep] autostart: kind = "synthetic" takes no commands, so it runs no sweep')
    c = values["compensator"]
    if c["enabled"] and c["current_limit_a"] > limits.max_current_a:
        raise ConfigError(f"{where} [compensator] current_limit_a = {c['current_limit_a']:g} A exceeds the bench's "
                          f"command limit of {limits.max_current_a:g} A (its trip level less [bench] current_margin; "
                          "0 takes it)")
    return limits


def build_source(cfg: DaemonConfig, *, clear_faults: bool = False) -> RigSource | SyntheticSource | BenchSource:
    """The configured source (``cfg``: a checked :class:`~.daemon.DaemonConfig`); the output is off.
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
