"""The bench daemon: the pipeline, its log and its zenoh face, run as a systemd service.

``hystbench daemon --config daemon.toml``: every key is checked (a misspelt or mistyped one is
refused with the file and key named), the source is the simulated rig unless instruments are
configured, and the process speaks systemd's notify protocol (READY, RELOADING, STOPPING,
WATCHDOG).  SIGTERM/SIGINT: output off, pipeline drained, log finished, exit 0.  SIGHUP: the file
is read again; a bad one is refused and the running configuration stays; a good one restarts
the pipeline (a new log part) and, if its [zenoh] section changed, the zenoh session.
"""

from __future__ import annotations

import copy
import logging
import signal
import threading
import time
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from .. import __version__
from ..config.schema import NUM, Key
from ..errors import BenchError, ConfigError
from .mcaplog.recorder import COMPRESSIONS
from .sd_notify import Notifier

__all__ = ["load_daemon_config", "DaemonConfig", "BenchService", "run_daemon", "DEFAULTS"]

log = logging.getLogger("hystbench.daemon")

_NUM = NUM
#: No new samples for this long and the watchdog is no longer fed.
STALL_S = 5.0
#: section -> key -> :class:`Key` (type, default, unit, legal range, meaning).  docs/config.md is
#: generated from this table (``python -m hystbench.config_reference``).
DEFAULTS: dict[str, dict[str, Key]] = {
    "daemon": {
        "bench": Key(str, "bench1", "the bench's name: the zenoh key space is hystbench/<bench>/... (no / * $ ? #)"),
        "log_dir": Key(str, "hystbench-logs", "folder of the MCAP logs, one per session: <bench>-<start time>-NNNN.mcap"),
        "stats_interval_s": Key(_NUM, 1.0, "period of the pipeline counters on hystbench/<bench>/stats", "s", gt=0),
    },
    "source": {
        "kind": Key(str, "bench", "bench: the instruments of bench_file through the drivers; sim: the simulated "
                    "rig directly (cheap); synthetic: precomputed sines", choices=("bench", "sim", "synthetic")),
        "rig": Key(str, "ecore_pm", "the rig preset (hystbench/config/rigs) or a .toml path; names the recordings"),
        "fs_hz": Key(_NUM, 100_000.0, "sample rate (kind = sim, synthetic; a bench file sets its own)", "Hz", gt=0),
        "block_samples": Key(int, 1000, "samples per block (kind = sim, synthetic)", "samples", gt=0),
        "seed": Key(int, 0, "random seed of the simulated rig's noise", ge=0),
        "frequency_hz": Key(_NUM, 320.0, "excitation frequency when the output is switched on without a sweep",
                            "Hz", gt=0),
        "current_pp_a": Key(_NUM, 1.4, "excitation current, peak to peak, without a sweep", "A", ge=0),
        "pace": Key(str, "realtime", "realtime: blocks at the sample clock; max: as fast as computed",
                    choices=("realtime", "max")),
        "effects": Key(dict, {}, "switches on top of the rig preset's, e.g. { sensor_noise = false }"),
        "ring_seconds": Key(_NUM, 2.0, "how far a stage may fall behind before it loses samples", "s", gt=0),
        "bench_file": Key(str, "", "kind = bench: the bench file (\"\": hystbench/config/bench.toml, every "
                          "instrument emulated)"),
    },
    "estimation": {
        "enabled": Key(bool, True, "estimate the delays live (hystbench/<bench>/estimate)"),
        "periods": Key(_NUM, 10.0, "window length in whole periods of the excitation", "periods", gt=0),
        "hop_periods": Key(_NUM, 10.0, "one estimate per this many periods ...", "periods", gt=0),
        "min_hop_s": Key(_NUM, 0.1, "... but at most one per this time", "s", ge=0),
        "settle_periods": Key(_NUM, 2.0, "skipped after each change of operating point", "periods", ge=0),
        "max_fs_hz": Key(_NUM, 100_000.0, "above this rate channels are averaged down before fitting", "Hz", gt=0),
    },
    "recording": {
        "enabled": Key(bool, True, "write the MCAP log"),
        "compression": Key(str, "zstd", "chunk compression", choices=COMPRESSIONS),
        "chunk_kib": Key(int, 256, "chunk size: a crash loses at most the open chunk", "KiB", gt=0),
        "flush_interval_s": Key(_NUM, 0.5, "the open chunk is written at least this often", "s", gt=0),
        "rotate_mib": Key(_NUM, 1024.0, "a new log part when the current one reaches this size", "MiB", gt=0),
        "rotate_minutes": Key(_NUM, 60.0, "... or this age", "min", gt=0),
    },
    "zenoh": {
        "enabled": Key(bool, True, "publish on zenoh and answer queries and commands"),
        "config": Key(str, "", "a zenoh json5 file (e.g. hystbench/config/zenoh-acl.json5); \"\": an embedded "
                      "peer, multicast scouting off"),
        "listen": Key(list, ["tcp/127.0.0.1:7447"], "endpoints to listen on (replace the config file's when given)"),
        "connect": Key(list, [], "endpoints to connect to (replace the config file's when given)"),
        "publish_raw": Key(bool, True, "raw blocks on hystbench/<bench>/raw, one message per block"),
        "raw_per_channel": Key(bool, False, "... or one per channel on hystbench/<bench>/raw/<channel>"),
    },
    "sweep": {
        "frequencies_hz": Key(list, [40.0, 80.0, 160.0, 320.0, 480.0], "what cmd/start_sweep runs when not told "
                              "otherwise: a non-empty list of frequencies > 0", "Hz"),
        "current_pp_a": Key(_NUM, 1.4, "sweep current, peak to peak", "A", ge=0),
        "dwell_s": Key(_NUM, 1.0, "time at each frequency", "s", gt=0),
        "autostart": Key(bool, False, "start one sweep when the daemon starts"),
    },
    "compensator": {
        "enabled": Key(bool, False, "feed-forward: follows the live hysteresis delay, uploads its current table"),
        "factory": Key(str, "", "or \"module:callable\" returning an object with update(estimate) -> state"),
        "model": Key(str, "", "a file from `hystbench model fit SWEEP_DIR --out MODEL.json`"),
        "kind": Key(str, "best", "which model of the file", choices=("nonhysteretic", "paper", "best")),
        "force": Key(str, "", "the force reference, e.g. \"offset=170,amp=40,freq=320\""),
        "current_limit_a": Key(_NUM, 1.8, "the compensator never commands more than this", "A", gt=0),
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


def _check(section: str, k: str, v: Any, where: str) -> Any:
    spec = DEFAULTS[section][k]
    name = f"{where} [{section}] {k}"
    bad = spec.problem(v)
    if bad:
        raise ConfigError(f"{name}: {bad}, got {v!r}")
    if section == "sweep" and k == "frequencies_hz" and (not v or not all(
            isinstance(f, _NUM) and not isinstance(f, bool) and f > 0 for f in v)):
        raise ConfigError(f"{name}: must be a non-empty list of frequencies > 0 Hz, got {v!r}")
    if section == "zenoh" and k in ("listen", "connect") and not all(isinstance(e, str) for e in v):
        raise ConfigError(f"{name}: must be a list of endpoints like 'tcp/127.0.0.1:7447', got {v!r}")
    return float(v) if spec.kind is _NUM else v


def load_daemon_config(path: str | Path | None) -> DaemonConfig:
    """Read and check a daemon TOML file (None: the defaults)."""
    where = str(path) if path is not None else "(defaults)"
    data: dict[str, Any] = {}
    if path is not None:
        try:
            data = tomllib.loads(Path(path).read_text(encoding="utf-8"))
        except FileNotFoundError as err:
            raise ConfigError(f"{path}: no such file") from err
        except (OSError, UnicodeDecodeError) as err:
            raise ConfigError(f"{path}: cannot read: {err}") from err
        except tomllib.TOMLDecodeError as err:
            raise ConfigError(f"{path}: not valid TOML: {err}") from err
    values = {s: {k: copy.deepcopy(d.default) for k, d in keys.items()} for s, keys in DEFAULTS.items()}
    given = set()
    for section, table in data.items():
        if section not in DEFAULTS:
            raise ConfigError(f"{where}: unknown section [{section}]; known: {', '.join(DEFAULTS)}")
        if not isinstance(table, dict):
            raise ConfigError(f"{where}: [{section}] must be a table")
        for k, v in table.items():
            if k not in DEFAULTS[section]:
                raise ConfigError(f"{where} [{section}]: unknown key {k!r}; known: {', '.join(DEFAULTS[section])}")
            values[section][k] = _check(section, k, v, where)
            given.add((section, k))
    from .zenoh_bus import key

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
    return DaemonConfig(values, frozenset(given), where)


def build_source(cfg: DaemonConfig):
    """The configured source (the simulated rig when no instruments are configured)."""
    from .sources import RigSource, SyntheticSource, bench_source

    s = cfg["source"]
    if s["kind"] == "synthetic":
        return SyntheticSource(fs_hz=s["fs_hz"], frequency_hz=s["frequency_hz"], block_samples=s["block_samples"],
                               pace=s["pace"], rig=s["rig"], current_pp_a=s["current_pp_a"], seed=s["seed"])
    if s["kind"] == "bench":
        return bench_source(s["bench_file"] or None, rig=s["rig"])
    from ..sim_backend.rig import SimulatedRig

    try:
        rig = SimulatedRig(s["rig"], fs_hz=s["fs_hz"], seed=s["seed"], effects=s["effects"] or None,
                           frequency_hz=s["frequency_hz"], current_pp_a=s["current_pp_a"])
    except ConfigError as err:
        raise ConfigError(f"{cfg.source} [source]: {err}") from None
    rig.output_enabled = False  # nothing is driven until a sweep or a command says so
    return RigSource(rig, block_samples=s["block_samples"], pace=s["pace"])


def zenoh_config(cfg: DaemonConfig):
    from .zenoh_bus import load_zenoh_config

    z = cfg["zenoh"]
    src = z["config"] or None
    listen = z["listen"] if (src is None or ("zenoh", "listen") in cfg.given) else None
    connect = z["connect"] if (src is None or ("zenoh", "connect") in cfg.given) else None
    return load_zenoh_config(src, listen=listen, connect=connect)


def _load_compensator(c: dict, source):
    """The compensator stage in a CompensatorHook: from ``model`` (a `hystbench model fit` file),
    ``kind`` and ``force`` (a reference such as "offset=170,amp=40,freq=320"), or from a
    ``factory = "module:callable"`` for anything else."""
    import importlib

    from .pipeline import CompensatorHook

    factory = c["factory"]
    if not factory:
        from ..compensator import CompensatorStage, ForceReference, LearningConfig, ModelSet

        if not c["model"] or not c["force"]:
            raise ConfigError("[compensator] enabled: give model and force (or a factory)")
        try:
            reference = ForceReference.parse(c["force"])
        except ValueError as err:
            raise ConfigError(f"[compensator] force {c['force']!r}: {err}") from err
        models = ModelSet.load(c["model"])
        try:
            learning = LearningConfig(gain=c["learning_gain"]) if c["learn"] else None
        except ValueError as err:
            raise ConfigError(f"[compensator] learning_gain: {err}") from err
        stage = CompensatorStage(models[c["kind"]], reference, current_limit_a=c["current_limit_a"],
                                 learning=learning, instrument=models.instrument)
        return CompensatorHook(stage, source)
    mod, _, attr = factory.partition(":")
    try:
        obj = getattr(importlib.import_module(mod), attr or "make_compensator")
    except (ImportError, AttributeError) as err:
        raise ConfigError(f"[compensator] factory {factory!r}: {err}") from err
    return CompensatorHook(obj(), source)


def _log_path(folder: Path, bench: str) -> Path:
    """``<bench>-<start time>.mcap`` (parts ``...-0001.mcap``), made unique within the second."""
    stem = f"{bench}-{time.strftime('%Y%m%d-%H%M%S')}"
    k = 1
    while (folder / f"{stem}-0001.mcap").exists() or (folder / f"{stem}.mcap").exists():
        k += 1
        stem = f"{bench}-{time.strftime('%Y%m%d-%H%M%S')}.{k}"
    return folder / f"{stem}.mcap"


class BenchService:
    """One configuration running: source -> pipeline -> MCAP log + zenoh, with sweeps and commands.

    ``session`` (optional) is a zenoh session to reuse (the daemon keeps it across reloads whose
    [zenoh] section did not change); otherwise one is opened from the config and owned here."""

    def __init__(self, cfg: DaemonConfig, *, session=None) -> None:
        self.cfg = cfg
        self.source = build_source(cfg)
        self.session = session
        self.pipeline = None
        self.recorder = None
        self.bus = None
        self.started = time.monotonic()
        self._sweep_stop = threading.Event()
        self._sweep: threading.Thread | None = None
        self.state = "starting"
        self.estimates = 0
        self.last_error = ""

    def start(self) -> "BenchService":
        from .mcaplog.recorder import McapRecorder
        from .pipeline import Pipeline
        from .stages import WindowEstimator
        from .zenoh_bus import ZenohBus

        c = self.cfg
        meta = {"recording": self.source.metadata(), "config": c.as_dict()}
        rig = getattr(getattr(self.source, "rig", None), "preset", None)
        if rig:
            meta["rig"] = {k: v for k, v in rig.items() if not k.startswith("_")}
        try:
            e = c["estimation"]
            comp = _load_compensator(c["compensator"], self.source) if c["compensator"]["enabled"] else None
            est = WindowEstimator(self.source.fs_hz, self.source.metadata(), periods=e["periods"],
                                  hop_periods=e["hop_periods"], min_hop_s=e["min_hop_s"],
                                  settle_periods=e["settle_periods"], max_fs_hz=e["max_fs_hz"],
                                  keep_windows=bool(comp and comp.wants_windows)) if e["enabled"] else None
            if c["recording"]["enabled"]:
                r = c["recording"]
                self.recorder = McapRecorder(_log_path(Path(c["daemon"]["log_dir"]), c["daemon"]["bench"]),
                                             metadata=meta, compression=r["compression"], chunk_size=r["chunk_kib"] * 1024,
                                             flush_interval_s=r["flush_interval_s"],
                                             rotate_bytes=int(r["rotate_mib"] * 2**20), rotate_s=r["rotate_minutes"] * 60)
                self.recorder.start()
            if c["zenoh"]["enabled"]:
                self.bus = ZenohBus(c["daemon"]["bench"], None if self.session else zenoh_config(c),
                                    on_command=self.command, config_provider=c.as_dict,
                                    health_provider=self.health, session=self.session,
                                    per_channel=c["zenoh"]["raw_per_channel"]).open()
            self.pipeline = Pipeline(self.source, estimator=est, recorder=self.recorder, bus=self.bus, compensator=comp,
                                     ring_seconds=c["source"]["ring_seconds"], stats_interval_s=c["daemon"]["stats_interval_s"],
                                     publish_raw=c["zenoh"]["publish_raw"])
            self.pipeline.listeners.append(self._count)
            self.pipeline.start()
        except BaseException:
            self.stop()
            raise
        self.state = "running"
        if c["sweep"]["autostart"]:
            self.command("start_sweep", {})
        return self

    def _count(self, topic: str, obj: dict) -> None:
        if topic == "/estimate":
            self.estimates += 1
            if obj.get("error"):
                self.last_error = str(obj["error"])

    def stop(self, timeout_s: float = 10.0) -> list[Path]:
        """Output off first, then the pipeline drains, the log is finished, zenoh is closed."""
        self.state = "stopping"
        self._sweep_stop.set()
        if hasattr(self.source, "set_output"):
            self.source.set_output(False)
        if self._sweep is not None:
            self._sweep.join(timeout=2.0)
        if self.pipeline is not None:
            self.pipeline.status("info", "stopping", "output off, finishing the log")
            self.pipeline.stop(timeout_s)
        self.source.close()
        paths = self.recorder.finish() if self.recorder is not None else []
        if self.bus is not None:
            self.bus.close()
        self.state = "stopped"
        return paths

    # --- commands (zenoh cmd/<verb>) -------------------------------------------------------------
    def _controllable(self):
        from .sources import Controllable

        if not isinstance(self.source, Controllable):
            raise ConfigError(f"source {self.source.name!r} takes no commands")
        return self.source

    def _tripped(self) -> str:
        """Why the compensator switched the output off, or ''."""
        return str(getattr(getattr(self.pipeline, "compensator", None), "tripped", "") or "")

    def command(self, verb: str, args: dict) -> dict:
        if self.pipeline is None or self.state not in ("running", "sweeping"):
            raise ConfigError(f"bench is {self.state}; try again when it is running")
        src = self._controllable()
        if (verb == "start_sweep" or verb == "output" and args.get("on")) and self._tripped():
            raise ConfigError(f"{verb}: refused, the compensator switched the output off ({self._tripped()}); "
                              "reload the configuration (SIGHUP) to start again")
        if verb == "set_excitation":
            unknown = set(args) - {"frequency_hz", "current_pp_a", "offset_a"}
            if unknown:
                raise ConfigError(f"set_excitation: unknown argument(s) {sorted(unknown)}")
            src.set_excitation(**{k: float(v) for k, v in args.items()})
            return {"applied": args}
        if verb == "output":
            src.set_output(bool(args.get("on", False)))
            return {"output_on": bool(args.get("on", False))}
        if verb == "stop_sweep":
            self._sweep_stop.set()
            src.set_output(False)
            return {"stopped": True}
        if verb == "start_sweep":
            sw = self.cfg["sweep"]
            freqs = [float(f) for f in args.get("frequencies_hz", sw["frequencies_hz"])]
            ipp, dwell = float(args.get("current_pp_a", sw["current_pp_a"])), float(args.get("dwell_s", sw["dwell_s"]))
            if not freqs or any(not 0 < f < self.source.fs_hz / 2 for f in freqs) or ipp < 0 or dwell <= 0:
                raise ConfigError(f"start_sweep: frequencies in (0, fs/2), current_pp_a >= 0 and dwell_s > 0 needed; "
                                  f"got {freqs}, {ipp}, {dwell}")
            if self._sweep is not None and self._sweep.is_alive():
                raise ConfigError("start_sweep: a sweep is running; stop_sweep first")
            self._sweep_stop = threading.Event()
            self._sweep = threading.Thread(target=self._run_sweep, args=(freqs, ipp, dwell, self._sweep_stop),
                                           name="sweep", daemon=True)
            self._sweep.start()
            return {"points": len(freqs), "duration_s": len(freqs) * dwell}
        raise ConfigError(f"unknown command {verb!r}")

    def _run_sweep(self, freqs: list[float], ipp: float, dwell: float, stop: threading.Event) -> None:
        src, p = self.source, self.pipeline
        self.state = "sweeping"
        p.status("info", "sweep_started", f"{len(freqs)} points at {ipp:g} A-pp, {dwell:g} s each")
        try:
            for k, f in enumerate(freqs):
                if self._tripped():
                    p.status("warning", "sweep_stopped", f"stopped at point {k}: {self._tripped()}")
                    return
                src.set_excitation(frequency_hz=f, current_pp_a=ipp)
                src.set_output(True)
                p.status("info", "sweep_point", f"{f:g} Hz, {ipp:g} A-pp", point=k, frequency_Hz=f, current_pp_A=ipp)
                if stop.wait(dwell):
                    p.status("info", "sweep_stopped", f"stopped at point {k}")
                    return
            p.status("info", "sweep_done", f"{len(freqs)} points")
        finally:
            src.set_output(False)
            if self.state == "sweeping":
                self.state = "running"

    def health(self) -> dict:
        p = self.pipeline
        return {"bench": self.cfg["daemon"]["bench"], "state": self.state, "version": __version__,
                "uptime_s": time.monotonic() - self.started, "source": self.source.name,
                "log": str(self.recorder.paths[-1]) if self.recorder and self.recorder.paths else None,
                "samples": p.stats["source"].samples if p else 0, "estimates": self.estimates,
                "pipeline_error": repr(p.error) if p and p.error else None, "last_estimate_error": self.last_error}


def run_daemon(config_path: str | Path | None) -> int:
    """The service's main loop; returns the exit status (0 after SIGTERM)."""
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(levelname)s %(message)s")
    cfg = load_daemon_config(config_path)
    notifier = Notifier()
    wake = threading.Event()
    flags = {"stop": False, "reload": False}

    def on_signal(signum, _frame) -> None:
        flags["reload" if signum == signal.SIGHUP else "stop"] = True
        wake.set()

    for sig in (signal.SIGTERM, signal.SIGINT, signal.SIGHUP):
        signal.signal(sig, on_signal)
    session = _open_session(cfg)
    svc = BenchService(cfg, session=session).start()
    log.info("serving bench %r (config %s)", cfg["daemon"]["bench"], cfg.source)
    notifier.ready(f"bench {cfg['daemon']['bench']}: {svc.state}")
    status = 0
    seen, progress_t = -1, time.monotonic()
    while not flags["stop"]:
        wake.wait(min(notifier.watchdog_s or 1.0, 1.0))
        wake.clear()
        if svc.pipeline.error is not None:
            log.error("pipeline failed: %r; stopping", svc.pipeline.error)
            status = 1
            break
        samples = svc.pipeline.stats["source"].samples
        if samples != seen:
            seen, progress_t = samples, time.monotonic()
        if time.monotonic() - progress_t < STALL_S:  # a stalled source stops the pings: systemd restarts us
            notifier.ping()
        if flags["reload"] and not flags["stop"]:
            flags["reload"] = False
            notifier.reloading()
            svc, cfg, session = _reload(config_path, svc, cfg, session)
            notifier.ready(f"bench {cfg['daemon']['bench']}: {svc.state}")
    notifier.stopping("output off, finishing the log")
    paths = svc.stop()
    if session is not None:
        session.close()
    log.info("stopped; log %s", ", ".join(map(str, paths)) or "(none)")
    return status


def _open_session(cfg: DaemonConfig):
    if not cfg["zenoh"]["enabled"]:
        return None
    from .zenoh_bus import open_session

    return open_session(zenoh_config(cfg))


def _reload(path, svc: BenchService, cfg: DaemonConfig, session):
    """Check the file again; a bad one is refused (the old config keeps running)."""
    try:
        new = load_daemon_config(path)
        if new["source"]["kind"] != "bench":  # instruments cannot be opened twice: checked at start
            build_source(new).close()  # fails here, not after the old service is gone
    except BenchError as err:
        log.error("reload refused, keeping the running configuration: %s", err)
        svc.pipeline.status("error", "reload_refused", str(err))
        return svc, cfg, session
    svc.stop()
    zenoh_changed = new["zenoh"] != cfg["zenoh"]
    try:
        if zenoh_changed:
            if session is not None:
                session.close()
            session = None
            session = _open_session(new)
        svc = BenchService(new, session=session).start()
    except BenchError as err:  # e.g. the new port is taken, the log folder not writable
        log.error("reload failed (%s); restarting the previous configuration", err)
        if zenoh_changed:
            if session is not None:
                session.close()
            session = _open_session(cfg)
        return BenchService(cfg, session=session).start(), cfg, session
    svc.pipeline.status("info", "reloaded", f"config {new.source}")
    log.info("reloaded %s", new.source)
    return svc, new, session
