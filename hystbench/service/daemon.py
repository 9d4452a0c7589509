"""The bench daemon: the pipeline, its log and its zenoh face, run as a systemd service.

``hystbench daemon --config daemon.toml``: every key is checked (:mod:`.daemon_config`; a misspelt or mistyped one is
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
fault the daemon could not recover from, or instruments (or, with ``[zenoh] listen = []``, the
router it connects to) that cannot be reached at start.
"""

from __future__ import annotations

import logging
import signal
import socket
import sys
import threading
import time
from pathlib import Path

from ..errors import BenchError, ConfigError, InstrumentError, NetworkError
from .daemon_config import DaemonConfig, load_daemon_config, zenoh_config
from .sd_notify import Notifier
from .service import BenchService
from .service_log import check_log_dir
from .shutdown import end_after
from .source_config import build_source

__all__ = ["run_daemon", "STALL_S", "STOP_S"]

log = logging.getLogger("hystbench.daemon")

#: No new samples for this long and the watchdog is no longer fed.
STALL_S = 5.0
#: SIGTERM ends the daemon within this long in every state by default (``[daemon] stop_timeout_s``);
#: past it, the process ends at once.
STOP_S = 4.5


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
            bound = float(cfg["daemon"]["stop_timeout_s"])  # the running configuration's (a reload may change it)
            # also ends an interpreter whose shutdown waits on another library's threads
            end_after(bound, signal.Signals(signum).name, "the service", "[daemon] stop_timeout_s")
        flags["reload" if signum == signal.SIGHUP else "stop"] = True
        wake.set()

    for sig in (signal.SIGTERM, signal.SIGINT, signal.SIGHUP):
        signal.signal(sig, on_signal)
    try:
        claim = _Claim().take(cfg)
    except NetworkError as err:  # [zenoh] connect: the router is not up (yet): systemd may try again (exit 1)
        print(f"hystbench daemon: error: {cfg.source} [zenoh] connect: {err}", file=sys.stderr)
        return 1
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
        try:  # the pipeline's threads get half the bound: the log's footer and the rest need the other
            paths = svc.stop(timeout_s=0.5 * float(cfg["daemon"]["stop_timeout_s"]))
        finally:
            claim.release()
    log.info("stopped; log %s", ", ".join(map(str, paths)) or "(none)")
    return status


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
    f, old = new["foxglove"], cfg["foxglove"]
    if f["enabled"] and not (old["enabled"] and (old["host"], old["port"]) == (f["host"], f["port"])):
        if why := _endpoint_free(f"tcp/{f['host']}:{f['port']}"):
            raise ConfigError(f"{new.source} [foxglove] port: cannot serve Foxglove on {f['host']}:{f['port']}: {why}; "
                              "change [foxglove] port (or host)")


def _why(err: Exception) -> str:
    """What a refused or failed reload says: our errors as they are, others with their type."""
    return str(err) if isinstance(err, BenchError) else f"{type(err).__name__}: {err}"


def _reload(path, svc: BenchService, cfg: DaemonConfig, claim: _Claim):
    """Check the file again and all it needs; a bad one is refused (the old config keeps running,
    its sweep and log part untouched)."""
    try:
        new = load_daemon_config(path)
        _check_reload(new, cfg, claim)
    except Exception as err:  # a BenchError names the file and key; anything else is said with its traceback
        why = _why(err)
        log.error("reload refused, keeping the running configuration: %s", why, exc_info=not isinstance(err, BenchError))
        svc.pipeline.status("error", "reload_refused", why)
        return svc, cfg
    svc.stop()
    try:
        claim.take(new)
        svc = BenchService(new, session=claim.session).start()
    except Exception as err:  # e.g. the new port is taken, the log folder not writable, a bench file's
        # CAN interface python-can does not know: whatever it is, the running configuration comes back
        why = _why(err)
        log.error("reload failed (%s); restarting the previous configuration", why,
                  exc_info=not isinstance(err, BenchError))
        claim.take(cfg)
        svc = BenchService(cfg, session=claim.session).start()
        svc.pipeline.status("error", "reload_failed", why)
        return svc, cfg
    svc.pipeline.status("info", "reloaded", f"config {new.source}")
    _started(new, svc)
    return svc, new
