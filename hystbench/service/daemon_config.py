"""The daemon file: its schema (:data:`DEFAULTS`, :data:`SCHEMA`, from which docs/config.md is
generated), :func:`load_daemon_config` that reads and checks it into a :class:`DaemonConfig`, and
what is derived from the checked file alone (:func:`zenoh_config`).  Pure configuration: it opens no
instrument, no session and no log, so the process (:mod:`.daemon`), the running service
(:mod:`.service`) and the source it builds (:mod:`.source_config`) all import it, and it imports none
of them.

The ``[source]`` table is checked kind by kind (:func:`check_source`): every key is honoured or
refused, never ignored.

- ``kind = "bench"``: the bench file's instruments.  Its ``[bench] fs_hz`` and ``[sim]
  block_samples`` / ``pace`` set what ``fs_hz``, ``block_samples`` and ``pace`` would, so those
  are refused when given.  ``rig``, ``seed`` and ``effects`` replace the bench file's ``[sim]``
  ones when it emulates the instruments; with hardware only, ``seed`` and ``effects`` are refused
  (there is no simulation to seed or to switch effects in) and ``rig`` names the recordings.
  ``frequency_hz`` and ``current_pp_a`` set the generator's sine when the bench opens.
- ``kind = "sim"``: the simulated rig directly; ``bench_file`` is refused (nothing reads it).
- ``kind = "synthetic"``: precomputed sines; ``bench_file`` and ``effects`` are refused.

Effects are checked by the effect catalogue (:func:`~hystbench.config.effects.validate_effects`),
the excitation and the sweep against the bench's limits
(:mod:`hystbench.acquisition.bench_commands`): a value the daemon would refuse as a command is
refused in its file already.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Mapping

from ..acquisition.bench_commands import (MAX_DWELL_S, MIN_FREQUENCY_HZ, MIN_SAMPLES_PER_PERIOD, Limits, check_current,
                                          check_dwell, check_frequency)
from ..config import read_toml
from ..config.schema import NUM, Key, check_table
from ..drivers.protocols.bench_config import load_bench_config
from ..errors import ConfigError
from ..formats.mcaplog.recorder import COMPRESSIONS, IDLE_RAW
from ..messages import OperatingPoint

if TYPE_CHECKING:
    import zenoh

__all__ = ["DEFAULTS", "SCHEMA", "DaemonConfig", "load_daemon_config", "zenoh_config", "check_source",
           "bench_file_limits", "sweep_point_periods"]

_NUM = NUM
_ENDPOINT = Key(str, None, "endpoints like 'tcp/127.0.0.1:7447'")
#: section -> key -> :class:`Key` (type, default, unit, legal range, meaning).  The file is checked
#: against it by :func:`~hystbench.config.schema.check_table`, and docs/config.md is generated from
#: it (``python -m hystbench.reports.config_reference``).
DEFAULTS: dict[str, dict[str, Key]] = {
    "daemon": {
        "bench": Key(str, "bench1", "the bench's name: the zenoh key space is hystbench/<bench>/... (no / * $ ? #)"),
        "log_dir": Key(str, "", "folder of the MCAP logs, one per session: <bench>-<start time>-NNNN.mcap; \"\": "
                       "the state directory's logs folder ($STATE_DIRECTORY under systemd, else "
                       "$XDG_STATE_HOME/hystbench or ~/.local/state/hystbench)"),
        "stats_interval_s": Key(_NUM, 1.0, "period of the pipeline counters on hystbench/<bench>/stats", "s", gt=0,
                                le=3600),
        "stop_timeout_s": Key(_NUM, 4.5, "SIGTERM/SIGINT end the daemon within this long in every state (output off "
                              "first); past it the process ends at once with exit status 1. Keep it below "
                              "systemd's TimeoutStopSec", "s", gt=0, le=300),
    },
    "source": {
        "kind": Key(str, "bench", "bench: the instruments of bench_file through the drivers; sim: the simulated "
                    "rig directly (cheap); synthetic: precomputed sines", choices=("bench", "sim", "synthetic")),
        "rig": Key(str, "ecore_pm", "the rig preset (hystbench/config/rigs) or a .toml path; names the recordings; "
                   "kind = bench: the emulated rig (default: the bench file's [sim] rig)"),
        "fs_hz": Key(_NUM, 100_000.0, "sample rate (kind = sim, synthetic; a bench file sets its own)", "Hz", gt=0),
        "block_samples": Key(int, 1000, "samples per block (kind = sim, synthetic)", "samples", gt=0),
        "seed": Key(int, 0, "random seed of the simulated rig's noise (kind = bench: emulated only)", ge=0),
        "frequency_hz": Key(_NUM, 320.0, "excitation frequency when the output is switched on without a sweep "
                            "(checked against the bench: 1 Hz to fs/10)", "Hz", gt=0),
        "current_pp_a": Key(_NUM, 1.4, "excitation current, peak to peak, without a sweep (at most twice the "
                            "bench's current limit)", "A", ge=0),
        "pace": Key(str, "realtime", "realtime: blocks at the sample clock; max: as fast as computed",
                    choices=("realtime", "max")),
        "effects": Key(dict, {}, "switches on top of the rig preset's, e.g. { sensor_noise = false } (kind = bench: "
                       "emulated only, replacing the bench file's [sim] effects)"),
        "ring_seconds": Key(_NUM, 2.0, "how far a stage may fall behind before it loses samples", "s", gt=0,
                            le=60),
        "bench_file": Key(str, "", "kind = bench only: the bench file (\"\": hystbench/config/bench.toml, every "
                          "instrument emulated)"),
    },
    "estimation": {
        "enabled": Key(bool, True, "estimate the delays live (hystbench/<bench>/estimate)"),
        "periods": Key(_NUM, 10.0, "window length in whole periods of the excitation", "periods", ge=2,
                       le=1000),
        "hop_periods": Key(_NUM, 10.0, "one estimate per this many periods ...", "periods", gt=0, le=1000),
        "min_hop_s": Key(_NUM, 0.1, "... but at most one per this time", "s", ge=0, le=3600),
        "settle_periods": Key(_NUM, 2.0, "skipped after each change of operating point", "periods", ge=0,
                              le=1000),
        "max_fs_hz": Key(_NUM, 100_000.0, "above this rate channels are averaged down before fitting", "Hz",
                         ge=1000),
    },
    "recording": {
        "enabled": Key(bool, True, "write the MCAP log"),
        "compression": Key(str, "zstd", "chunk compression", choices=COMPRESSIONS),
        "chunk_kib": Key(int, 256, "chunk size: a crash loses at most the open chunk", "KiB", gt=0),
        "flush_interval_s": Key(_NUM, 0.5, "the open chunk is written at least this often", "s", gt=0),
        "rotate_mib": Key(_NUM, 1024.0, "a new log part when the current one reaches this size", "MiB", gt=0),
        "rotate_minutes": Key(_NUM, 60.0, "... or this age", "min", gt=0),
        "idle_raw": Key(str, "decimated", "raw samples while the output is off: off (none), decimated (the first "
                        "10 ms of every second: offsets, noise, pickup) or full", choices=IDLE_RAW),
        "keep_days": Key(_NUM, 0.0, "retention: delete this bench's log parts older than this (0: keep them)",
                         "days", ge=0),
        "max_total_gib": Key(_NUM, 100.0, "retention: delete this bench's oldest log parts while they add up to "
                             "more than this (0: no limit); the open part is never deleted", "GiB", ge=0),
    },
    "zenoh": {
        "enabled": Key(bool, True, "publish on zenoh and answer queries and commands"),
        "config": Key(str, "", "a zenoh json5 file (e.g. hystbench/config/zenoh-acl.json5); \"\": an embedded "
                      "peer, multicast scouting off"),
        "listen": Key(list, ["tcp/127.0.0.1:7447"], "endpoints to listen on (replace the config file's when given); "
                      "[] with a connect: a client of that zenoh router (a fleet, docs/zenoh.md)",
                      items=_ENDPOINT),
        "connect": Key(list, [], "endpoints to connect to (replace the config file's when given)", items=_ENDPOINT),
        "publish_raw": Key(bool, True, "raw blocks on hystbench/<bench>/raw, one message per block"),
        "raw_per_channel": Key(bool, False, "... or one per channel on hystbench/<bench>/raw/<channel>"),
    },
    "foxglove": {
        "enabled": Key(bool, False, "serve the live view to Foxglove (WebSocket, protocol foxglove.sdk.v1): the "
                       "decimated sample channels, estimates, compensator, status; docs/foxglove.md"),
        "host": Key(str, "127.0.0.1", "address to listen on (127.0.0.1: this PC only; the server has no "
                    "authentication, so reach it from elsewhere through an SSH tunnel)"),
        "port": Key(int, 8765, "TCP port of ws://<host>:<port> (Foxglove's default is 8765)", ge=1, le=65535),
        "plot_hz": Key(_NUM, 250.0, "points per second of each /plot/<channel>: samples are cut into bins of "
                       "round(fs_hz / plot_hz)", "Hz", ge=1, le=5000),
    },
    "sweep": {
        "frequencies_hz": Key(list, [40.0, 80.0, 160.0, 320.0, 480.0], "what cmd/start_sweep runs when not told "
                              "otherwise", "Hz", items=Key(_NUM, None, "frequencies", "Hz", gt=0), nonempty=True),
        "current_pp_a": Key(_NUM, 1.4, "sweep current, peak to peak", "A", ge=0),
        "dwell_s": Key(_NUM, 1.0, "time at each frequency", "s", gt=0, le=MAX_DWELL_S),
        "autostart": Key(bool, False, "start one sweep when the daemon starts"),
    },
    "compensator": {
        "enabled": Key(bool, False, "feed-forward: follows the live hysteresis delay, uploads its current table"),
        "factory": Key(str, "", "or \"module:callable\" returning an object with update(estimate) -> "
                       "hystbench.messages.CompensatorUpdate (state, output_off, waveform_a, frequency_hz) or None"),
        "model": Key(str, "", "a file from `hystbench model fit SWEEP_DIR --out MODEL.json`"),
        "kind": Key(str, "best", "which model of the file", choices=("nonhysteretic", "paper", "best")),
        "force": Key(str, "", "the force reference, e.g. \"offset=170,amp=40,freq=320\""),
        "current_limit_a": Key(_NUM, 0.0, "the compensator never commands more than this (0: the bench's command "
                               "limit, its trip level less [bench] current_margin)", "A", ge=0),
        "learn": Key(bool, False, "repetitive control on each estimate window's period-averaged force"),
        "learning_gain": Key(_NUM, 0.8, "gain of the learning loop; it stops itself, output off, if it diverges",
                             gt=0, le=1.5),
    },
}


@dataclass(frozen=True)
class DaemonConfig:
    """The checked configuration: ``values[section][key]``, every key present; ``given`` holds the
    keys the file set (so a zenoh config file keeps its endpoints unless the TOML names them)."""

    values: dict[str, dict[str, Any]]
    given: frozenset[tuple[str, str]]
    source: str

    def __getitem__(self, section: str) -> dict[str, Any]:
        return self.values[section]

    def as_dict(self) -> dict[str, Any]:
        return copy.deepcopy(self.values)


#: The daemon file's schema: one table per section of :data:`DEFAULTS`, each optional.
SCHEMA: dict[str, Key] = {s: Key(dict, {}, f"[{s}]", table=keys) for s, keys in DEFAULTS.items()}


def load_daemon_config(path: str | Path | None) -> DaemonConfig:
    """Read and check a daemon TOML file (None: the defaults)."""
    where = str(path) if path is not None else "(defaults)"
    data = read_toml(path) if path is not None else {}
    data = _bench_file_as_daemon_config(data, path, where)
    values = check_table(data, where, SCHEMA)
    given = {(s, k) for s, table in data.items() for k in table}
    from ..acquisition.zenoh_bus import key

    try:
        key(values["daemon"]["bench"])
    except ConfigError as err:
        raise ConfigError(f"{where} [daemon] bench: {err}") from None
    from ..config import load_rig

    try:  # every kind: the rig names the recordings (the interchange format's 'rig' key)
        load_rig(values["source"]["rig"])
    except ConfigError as err:
        raise ConfigError(f"{where} [source] rig: {err}") from None
    if values["compensator"]["enabled"] and not values["estimation"]["enabled"]:
        raise ConfigError(f"{where} [compensator] enabled needs [estimation] enabled: the compensator follows "
                          "the live estimates (and learns on their windows)")
    for k in ("bench_file",):  # relative paths: from where the daemon was started, made absolute now
        if values["source"][k]:
            values["source"][k] = str(Path(values["source"][k]).expanduser().absolute())
    check_source(values, given, where)
    d = values["daemon"]
    if d["log_dir"]:
        d["log_dir"] = str(Path(d["log_dir"]).expanduser().absolute())
    else:
        from .instance import default_log_dir

        d["log_dir"] = str(default_log_dir()[0])
    return DaemonConfig(values, frozenset(given), where)


def _bench_file_as_daemon_config(data: dict[str, Any], path, where: str) -> dict[str, Any]:
    """A bench file given as the daemon's config (it has a [bench] table): the daemon's defaults
    with ``[source] kind = "bench"`` and that file, which is checked as a bench file."""
    if "bench" not in data or path is None:
        return data
    mixed = sorted(set(data) & set(DEFAULTS))
    if mixed:
        raise ConfigError(f"{where}: has a bench file's [bench] table and the daemon's [{mixed[0]}]; keep them "
                          "apart and name the bench file in the daemon file's [source] bench_file")
    return {"source": {"kind": "bench", "bench_file": str(path)}}


def zenoh_config(cfg: DaemonConfig) -> zenoh.Config:
    """The session's config: the [zenoh] config file (or a bare peer) with the daemon file's
    ``listen``/``connect`` on top only where the file names them, so a zenoh file keeps its own."""
    from ..acquisition.zenoh_bus import load_zenoh_config

    z = cfg["zenoh"]
    src = z["config"] or None
    listen = z["listen"] if (src is None or ("zenoh", "listen") in cfg.given) else None
    connect = z["connect"] if (src is None or ("zenoh", "connect") in cfg.given) else None
    return load_zenoh_config(src, listen=listen, connect=connect, serve=True)  # bounded, listening or not


_SET_BY_BENCH_FILE = {"fs_hz": "[bench] fs_hz", "block_samples": "[sim] block_samples", "pace": "[sim] pace"}


def bench_file_limits(bench_file: str | None = None) -> Limits:
    """Sample rate and peak current limit of a bench file (None: the shipped one, which also
    stands for the simulated rig: the same amplifier and limits)."""
    cfg = load_bench_config(bench_file or None)
    return Limits(cfg.fs_hz, cfg.current_limit_a)


def _validate_effects(effects: dict, where: str, fs_hz: float) -> None:
    from ..config.effects import validate_effects

    validate_effects(effects, f"{where} [source] effects", fs_hz=fs_hz)


def _check_emulated_channels(rig: str, refuse: Any) -> None:
    """A rig the emulated bench cannot stream (``emulators.bench.missing_channels``), refused by key:
    the daemon said it was running and answered every command ok, with no sample ever."""
    from ..sim_backend.emulators.bench import missing_channels

    if missing := missing_channels(rig):
        refuse("rig", f"{missing}; run it as kind = \"sim\"")



def _playable(limits: Limits, what: str) -> Limits:
    """``limits``, refused when their sample rate leaves no frequency to play (1e-300 S/s was refused
    as "frequency_hz = 320 Hz is outside [1, 1e-301] Hz", blaming the frequency)."""
    if limits.max_frequency_hz < MIN_FREQUENCY_HZ:
        raise ConfigError(f"{what}: {limits.fs_hz:g} Hz is too slow to play any frequency: {MIN_SAMPLES_PER_PERIOD} "
                          f"samples per period of the lowest, {MIN_FREQUENCY_HZ:g} Hz, need at least "
                          f"{MIN_SAMPLES_PER_PERIOD * MIN_FREQUENCY_HZ:g} Hz")
    return limits


def sweep_point_periods(values: Mapping[str, Any]) -> tuple[float, str]:
    """The whole periods each point of a sweep needs, and what needs them: the estimator's settle and
    window when it estimates live, else one period (a point played for less is never seen whole)."""
    e = values["estimation"]
    if e["enabled"]:
        return (e["settle_periods"] + e["periods"],
                f"[estimation] settle_periods {e['settle_periods']:g} + periods {e['periods']:g}")
    return 1.0, "to be seen whole"

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
            _check_emulated_channels(s["rig"], refuse)
        else:
            for k in ("seed", "effects"):
                if ("source", k) in given and (k == "seed" or s[k]):
                    refuse(k, f"applies to the emulated rig, and {bench.source} has hardware instruments only")
        limits = _playable(Limits(bench.fs_hz, bench.current_limit_a), f"{bench.source} [bench] fs_hz")
    else:
        if s["bench_file"]:
            refuse("bench_file", f'only kind = "bench" reads a bench file (kind is "{kind}")')
        if kind == "synthetic" and s["effects"]:
            refuse("effects", 'synthetic sines have no physical effects; use kind = "sim" or "bench"')
        if kind == "sim":
            _validate_effects(s["effects"], where, s["fs_hz"])
            from ..drivers.protocols.bench_config import check_tick

            check_tick(s["block_samples"], s["fs_hz"], f"{where} [source] block_samples = {s['block_samples']}")
        from ..acquisition.sources import MAX_BLOCK_SAMPLES

        if s["block_samples"] > MAX_BLOCK_SAMPLES:
            refuse("block_samples", f"must be at most {MAX_BLOCK_SAMPLES:.0e} (a block is computed and held whole), "
                                    f"got {s['block_samples']}")
        limits = _playable(Limits(s["fs_hz"], bench_file_limits().max_current_a), f"{where} [source] fs_hz")
    check_frequency(f"{where} [source] frequency_hz", s["frequency_hz"], limits)
    check_current(f"{where} [source]", OperatingPoint(s["frequency_hz"], s["current_pp_a"]), limits)
    if kind != "synthetic":  # a synthetic source takes no commands, so it runs no sweep
        sw = values["sweep"]
        for k, f in enumerate(sw["frequencies_hz"]):
            check_frequency(f"{where} [sweep] frequencies_hz[{k}]", f, limits)
        check_current(f"{where} [sweep]", OperatingPoint(sw["frequencies_hz"][0], sw["current_pp_a"]), limits)
        if sw["autostart"] or any(section == "sweep" for section, _ in given):  # a sweep this file asks for
            # (the defaults alone are checked when a start_sweep uses them: a long estimator window is no error)
            check_dwell(f"{where} [sweep] dwell_s: ", sw["dwell_s"], sw["frequencies_hz"], *sweep_point_periods(values))
    elif values["sweep"]["autostart"]:
        raise ConfigError(f'{where} [sweep] autostart: kind = "synthetic" takes no commands, so it runs no sweep')
    c = values["compensator"]
    if c["enabled"] and c["current_limit_a"] > limits.max_current_a:
        raise ConfigError(f"{where} [compensator] current_limit_a = {c['current_limit_a']:g} A exceeds the bench's "
                          f"command limit of {limits.max_current_a:g} A (its trip level less [bench] current_margin; "
                          "0 takes it)")
    return limits
