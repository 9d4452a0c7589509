"""The bench daemon: the pipeline, its log and its zenoh face, run as a systemd service.

``hystbench daemon --config daemon.toml``: every key is checked (a misspelt or mistyped one is
refused with the file and key named; a key the source's kind does not use is refused, naming
why), the source is the simulated rig unless instruments are configured, and the process speaks
systemd's notify protocol (READY, RELOADING, STOPPING, WATCHDOG).  ``--config`` also takes a
bench file (recognised by its ``[bench]`` table): the daemon's defaults with that bench.

One daemon per bench (:mod:`.instance`: a lock file in the state directory and a zenoh
liveliness token); logs in ``[daemon] log_dir`` or the state directory's ``logs`` folder.
Commands are checked before they are answered and a fault restarts the source and pipeline,
output off (:mod:`.service`); a log folder that refuses writes pauses the log, not the service
(:mod:`.service_log`).  SIGTERM/SIGINT: output off, pipeline drained, log finished, exit 0,
within ``STOP_S`` in every state (past it the process ends at once: the amplifier's watchdog
switches the output off when the heartbeat stops).  SIGHUP: the file is read again, and
everything it needs (its log folder, its bench's lock, its ports) is checked before the running
service is touched; a bad one is refused and the running configuration stays; a good one
restarts the pipeline (a new log part) and, if its [zenoh] section changed, the zenoh session.  Exit 2: a bad configuration (systemd does not restart into it); exit 1: a
fault the daemon could not recover from, or instruments that cannot be reached at start.
"""

from __future__ import annotations

import copy
import logging
import os
import signal
import socket
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ..config import read_toml
from ..config.schema import NUM, Key, check_table
from ..errors import BenchError, ConfigError, InstrumentError
from ..formats.mcaplog.recorder import COMPRESSIONS, IDLE_RAW
from ..acquisition.bench_commands import MAX_DWELL_S
from .sd_notify import Notifier
from .service import BenchService
from .service_log import check_log_dir
from .source_config import build_source, check_source

if TYPE_CHECKING:
    import zenoh

__all__ = ["load_daemon_config", "DaemonConfig", "BenchService", "run_daemon", "DEFAULTS", "build_source"]

log = logging.getLogger("hystbench.daemon")

_NUM = NUM
_ENDPOINT = Key(str, None, "endpoints like 'tcp/127.0.0.1:7447'")
#: No new samples for this long and the watchdog is no longer fed.
STALL_S = 5.0
#: SIGTERM ends the daemon within this long in every state; past it, the process ends at once.
STOP_S = 4.5
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
        "listen": Key(list, ["tcp/127.0.0.1:7447"], "endpoints to listen on (replace the config file's when given)",
                      items=_ENDPOINT),
        "connect": Key(list, [], "endpoints to connect to (replace the config file's when given)", items=_ENDPOINT),
        "publish_raw": Key(bool, True, "raw blocks on hystbench/<bench>/raw, one message per block"),
        "raw_per_channel": Key(bool, False, "... or one per channel on hystbench/<bench>/raw/<channel>"),
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
        "factory": Key(str, "", "or \"module:callable\" returning an object with update(estimate) -> state"),
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


def run_daemon(config_path: str | Path | None) -> int:
    """The service's main loop; returns the exit status (0 after SIGTERM, 1 after a fault it could
    not recover from or instruments it could not reach at start); a bad configuration, a bench
    already served or a port already taken raise ConfigError (the command line's exit 2)."""
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(levelname)s %(message)s")
    cfg = load_daemon_config(config_path)
    notifier = Notifier()
    wake = threading.Event()
    flags = {"stop": False, "reload": False}

    def on_signal(signum, _frame) -> None:
        if signum != signal.SIGHUP and not flags["stop"]:  # whatever the main loop is busy with
            timer = threading.Timer(STOP_S, _stop_now, args=(signal.Signals(signum).name,))
            timer.daemon = True  # also ends an interpreter whose shutdown waits on another library's threads
            timer.start()
        flags["reload" if signum == signal.SIGHUP else "stop"] = True
        wake.set()

    for sig in (signal.SIGTERM, signal.SIGINT, signal.SIGHUP):
        signal.signal(sig, on_signal)
    claim = _Claim().take(cfg)
    try:
        svc = BenchService(cfg, session=claim.session).start()
    except InstrumentError as err:  # not the file's fault: systemd may try again (exit 1)
        claim.release()
        print(f"hystbench daemon: error: {err}", file=sys.stderr)
        return 1
    except BaseException:
        claim.release()
        raise
    _started(cfg, svc)
    notifier.ready(f"bench {cfg['daemon']['bench']}: {svc.state}")
    status = 0
    seen, progress_t = -1, time.monotonic()
    try:
        while not flags["stop"]:
            wake.wait(min(notifier.watchdog_s or 1.0, 1.0))
            wake.clear()
            try:
                if svc.recover():
                    seen = -1
            except BenchError as err:
                log.error("cannot recover from the fault: %s; stopping", err)
                status = 1
                break
            samples = svc.pipeline.stats["source"].samples
            now = time.monotonic()
            if samples != seen:
                seen, progress_t = samples, now
            if now - progress_t < STALL_S:  # a stalled source stops the pings: systemd restarts us
                notifier.ping()
            svc.housekeeping()
            if flags["reload"] and not flags["stop"]:
                flags["reload"] = False
                notifier.reloading()
                svc, cfg = _reload(config_path, svc, cfg, claim)
                notifier.ready(f"bench {cfg['daemon']['bench']}: {svc.state}")
    finally:  # whatever ended the loop: output off, log finished, the bench's lock and port freed
        notifier.stopping("output off, finishing the log")
        try:
            paths = svc.stop()
        finally:
            claim.release()
    log.info("stopped; log %s", ", ".join(map(str, paths)) or "(none)")
    return status


def _stop_now(signame: str) -> None:
    """SIGTERM came ``STOP_S`` ago and the service has not stopped: end the process now.  The
    kernel frees the bench's lock and ports; with the heartbeat gone, the amplifier's watchdog
    switches the output off (the drivers tried first, in the stop that is hanging)."""
    log.error("%s: the service did not stop within %g s; exiting now", signame, STOP_S)
    logging.shutdown()
    os._exit(1)


def _started(cfg: DaemonConfig, svc: BenchService) -> None:
    from .instance import default_log_dir

    given = cfg.source != "(defaults)" and default_log_dir()[0] != Path(cfg["daemon"]["log_dir"])
    why = f"[daemon] log_dir of {cfg.source}" if given else f"default: {default_log_dir()[1]}"
    log.info("serving bench %r (config %s, source %s); logs in %s (%s)", cfg["daemon"]["bench"], cfg.source,
             svc.source.name, cfg["daemon"]["log_dir"], why)


class _Claim:
    """What makes this daemon the one of its bench: the lock file, the zenoh session and the
    liveliness token on it (kept across reloads while the bench and [zenoh] stay the same)."""

    def __init__(self) -> None:
        self.lock = None
        self.session = None
        self.zenoh: dict | None = None  # the [zenoh] section the session was opened for
        self.token = None
        self.token_bench: str | None = None

    def take(self, cfg: DaemonConfig) -> "_Claim":
        """Lock, session and token for ``cfg``, keeping what stays the same; a refusal
        (ConfigError) leaves the lock held as it was, and at worst the session closed."""
        from .instance import BenchLock, claim_on_zenoh

        bench = cfg["daemon"]["bench"]
        lock = self.lock if self.lock is not None and self.lock.bench == bench else \
            BenchLock(bench, endpoints=_endpoints(cfg), config=cfg.source).acquire()
        try:
            if self.zenoh != cfg["zenoh"]:
                self._close_session()  # the port may stay the same: free it first
                self.session = _open_session(cfg)
                self.zenoh = cfg["zenoh"]
            if self.session is not None and self.token_bench != bench:
                if self.token is not None:
                    self.token.undeclare()
                self.token, self.token_bench = None, None
                self.token = claim_on_zenoh(self.session, bench)
                self.token_bench = bench
        except BaseException:
            if lock is not self.lock:
                lock.release()
            raise
        if self.lock is not None and lock is not self.lock:
            self.lock.release()
        self.lock = lock
        return self

    def _close_session(self) -> None:
        if self.token is not None:
            self.token.undeclare()
        if self.session is not None:
            self.session.close()
        self.token = self.session = self.zenoh = self.token_bench = None

    def release(self) -> None:
        self._close_session()
        if self.lock is not None:
            self.lock.release()
            self.lock = None


def _endpoints(cfg: DaemonConfig) -> list[str]:
    return list(cfg["zenoh"]["listen"]) if cfg["zenoh"]["enabled"] else []


def _open_session(cfg: DaemonConfig):
    if not cfg["zenoh"]["enabled"]:
        return None
    from ..acquisition.zenoh_bus import ListenError, open_session

    try:
        return open_session(zenoh_config(cfg))
    except ListenError as err:
        raise ConfigError(f"{cfg.source} [zenoh] listen: {err}; change [zenoh] listen") from None


def _endpoint_free(endpoint: str) -> str:
    """Why a zenoh listen ``endpoint`` (``tcp/HOST:PORT``, ``udp/...``) cannot be bound now ('' :
    it can, or it is of a kind not checked here)."""
    proto, _, rest = endpoint.partition("/")
    host, _, port = rest.split("#")[0].split("?")[0].rpartition(":")
    if proto not in ("tcp", "udp") or not port.isdigit() or int(port) == 0:
        return ""
    kind = socket.SOCK_STREAM if proto == "tcp" else socket.SOCK_DGRAM
    try:
        for family, _, _, _, addr in socket.getaddrinfo(host.strip("[]") or None, int(port), type=kind):
            with socket.socket(family, kind) as s:
                s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # as a listener binds it
                s.bind(addr)
    except OSError as err:
        return err.strerror or str(err)
    return ""


def _check_reload(new: DaemonConfig, cfg: DaemonConfig, claim: _Claim) -> None:
    """Everything ``new`` needs that the running service does not hold already, checked before it
    is touched: a source it can build, a log folder it can write, its bench's lock, its ports."""
    from .instance import BenchLock

    if new["source"]["kind"] != "bench":  # instruments cannot be opened twice: checked at start
        build_source(new).close()
    if new["recording"]["enabled"]:
        check_log_dir(new["daemon"]["log_dir"], new.source)
    if new["daemon"]["bench"] != cfg["daemon"]["bench"]:
        BenchLock(new["daemon"]["bench"], config=new.source).acquire().release()
    if new["zenoh"]["enabled"] and new["zenoh"] != claim.zenoh:
        held = set(_endpoints(cfg))
        for endpoint in _endpoints(new):
            if endpoint not in held and (why := _endpoint_free(endpoint)):
                raise ConfigError(f"{new.source} [zenoh] listen: cannot listen on {endpoint}: {why}; change "
                                  "[zenoh] listen")


def _reload(path, svc: BenchService, cfg: DaemonConfig, claim: _Claim):
    """Check the file again and all it needs; a bad one is refused (the old config keeps running,
    its sweep and log part untouched)."""
    try:
        new = load_daemon_config(path)
        _check_reload(new, cfg, claim)
    except BenchError as err:
        log.error("reload refused, keeping the running configuration: %s", err)
        svc.pipeline.status("error", "reload_refused", str(err))
        return svc, cfg
    svc.stop()
    try:
        claim.take(new)
        svc = BenchService(new, session=claim.session).start()
    except BenchError as err:  # e.g. the new port is taken, the log folder not writable
        log.error("reload failed (%s); restarting the previous configuration", err)
        claim.take(cfg)
        svc = BenchService(cfg, session=claim.session).start()
        svc.pipeline.status("error", "reload_failed", str(err))
        return svc, cfg
    svc.pipeline.status("info", "reloaded", f"config {new.source}")
    _started(new, svc)
    return svc, new
