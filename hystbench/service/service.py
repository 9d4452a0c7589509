"""One daemon configuration running: source -> pipeline -> MCAP log + zenoh, sweeps and commands.

Nothing a command asks can end the service.  Every current put on the amplifier, whoever asked
for it (``set_excitation``, a sweep's next point), is checked with the operating point it will
really produce, offset included, when it is applied (:meth:`BenchService._apply`, and again by the
drivers' :class:`~hystbench.drivers.safety.CurrentBudget` when the source applies it), against the
bench's command limit (the trip level less its margin).  A fault in a stage (an instrument fault,
a lost connection, an error in the source thread) is met by :meth:`BenchService.recover`: the
output goes off, the fault is published on ``status`` and written to the log, the source and
pipeline start again (output off) in a new log part.  A fault the excitation caused (the amplifier
tripped OVERCURRENT or OVERTEMP, a driver refused a current) is a *trip*: it never counts towards
giving up; instead ``output on`` and ``start_sweep`` are refused until ``clear_fault``.  Only
faults the service cannot control, in quick succession (``MAX_FAULTS`` within
``FAULT_WINDOW_S``), or a source that cannot be opened again end it.
"""

from __future__ import annotations

import logging
import os
import threading
import time
from collections import deque
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING

from .. import __version__
from ..acquisition.bench_commands import MIN_FREQUENCY_HZ, Limits, check_command, check_current
from ..drivers.base import FaultLatched
from ..drivers.safety import SafetyLimitError
from ..errors import BenchError, CommandRefused, ConfigError
from ..messages import OperatingPoint
from .daemon_config import DaemonConfig, sweep_point_periods, zenoh_config
from .foxglove_live import FoxgloveLive
from .service_log import ServiceLog, check_log_dir
from .source_config import build_source

if TYPE_CHECKING:
    import zenoh

    from ..formats.mcaplog.recorder import McapRecorder

__all__ = ["BenchService", "TooManyFaults", "MAX_FAULTS", "FAULT_WINDOW_S", "COMMAND_FAULTS", "caused_by_command"]

log = logging.getLogger("hystbench.daemon")

#: More faults than this within FAULT_WINDOW_S and the service gives up (systemd restarts it).
MAX_FAULTS = 5
FAULT_WINDOW_S = 60.0
#: A sweep point whose source gives no sample for this long (wall time) ends the sweep with a
#: fault: a safety bound for a dead source, never a way for a dwell to finish.
DWELL_STALL_S = 30.0
#: How often a dwell looks at the stop request and the source's progress.
DWELL_POLL_S = 0.05
#: Latched amplifier faults that the excitation causes (too much current, or for too long).
COMMAND_FAULTS = frozenset({"OVERCURRENT", "OVERTEMP"})


def caused_by_command(err: BaseException | None) -> str:
    """Why ``err`` came from what the bench was told to drive ('' if it did not): a driver that
    refused a current, or an amplifier trip in :data:`COMMAND_FAULTS`, anywhere in its chain of
    causes.  Such a fault is the commander's to clear, not a reason to stop the service."""
    seen: set[int] = set()
    while err is not None and id(err) not in seen:
        seen.add(id(err))
        if isinstance(err, SafetyLimitError) or (
                isinstance(err, FaultLatched) and err.faults and set(err.faults) <= COMMAND_FAULTS):
            return str(err)
        err = err.__cause__ or err.__context__
    return ""


class TooManyFaults(BenchError):
    """More than ``MAX_FAULTS`` faults within ``FAULT_WINDOW_S``: restarting the source again would
    only meet the same fault, so the service stops (the daemon exits 1, systemd restarts it).  Not
    the class of the last fault (that may be an instrument's, the log's, the simulation's): the
    service's own verdict on all of them; the last one is its ``__cause__``."""


def _load_compensator(c: dict, source):
    """The compensator stage in a CompensatorHook: from ``model`` (a `hystbench model fit` file),
    ``kind`` and ``force`` (a reference such as "offset=170,amp=40,freq=320"), or from a
    ``factory = "module:callable"`` for anything else."""
    import importlib

    from ..acquisition.pipeline import CompensatorHook

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
        limit_a = c["current_limit_a"] or getattr(source, "max_current_a", None)  # 0: the bench's command limit
        if not limit_a:
            raise ConfigError(f"[compensator] current_limit_a: give one; {source.name} states no current limit")
        stage = CompensatorStage(models[c["kind"]], reference, current_limit_a=limit_a,
                                 learning=learning, instrument=models.instrument)
        return CompensatorHook(stage, source)
    mod, _, attr = factory.partition(":")
    try:
        obj = getattr(importlib.import_module(mod), attr or "make_compensator")
    except (ImportError, AttributeError) as err:
        raise ConfigError(f"[compensator] factory {factory!r}: {err}") from err
    if not callable(obj):
        raise ConfigError(f"[compensator] factory {factory!r}: {type(obj).__name__} {obj!r} is not callable; give "
                          "module:function, a function that makes the compensator")
    try:
        made = obj()
    except Exception as err:  # a user's code: its failure is the configuration's, said in one line
        raise ConfigError(f"[compensator] factory {factory!r}: calling it raised {type(err).__name__}: {err}") from err
    return CompensatorHook(made, source)


class BenchService:
    """One configuration running.  ``session`` (optional) is a zenoh session to reuse (the daemon
    keeps it across reloads whose [zenoh] section did not change); otherwise one is opened from
    the config and owned here."""

    def __init__(self, cfg: DaemonConfig, *, session: zenoh.Session | None = None) -> None:
        self.cfg = cfg
        self.source = build_source(cfg)
        self.session = session
        self.pipeline = None
        self.bus = None
        self.foxglove = None  # the live view (FoxgloveLive), with [foxglove] enabled
        self._said: list[tuple] = []  # statuses told before the pipeline runs
        self.log = ServiceLog(cfg, self._metadata, self._status)
        self.started = time.monotonic()
        self._sweep_stop = threading.Event()
        self._sweep: threading.Thread | None = None
        self._lock = threading.Lock()  # the commanded operating point: commands and the sweep
        self.state = "starting"
        self.estimates = 0
        self.last_error = ""
        #: faults the service cannot control (time, message): too many in a row end the service
        self.faults: deque[tuple[float, str]] = deque(maxlen=100)
        self.last_fault = ""
        self.trips = 0  # faults the excitation caused (caused_by_command): never end the service
        #: why the output may not be switched on until ``clear_fault`` ('' : it may)
        self.tripped = ""
        self.log_dir = Path(cfg["daemon"]["log_dir"])
        self._reset_point()

    @property
    def recorder(self) -> McapRecorder | None:
        """The open log's recorder (None: recording off, or paused after a write error)."""
        return self.log.recorder

    def _status(self, level: str, event: str, message: str = "", **extra) -> None:
        """A status of the service's own (the log's): said once a pipeline runs to say it."""
        self._said.append((level, event, message, extra))
        while self.pipeline is not None and self._said:
            level, event, message, extra = self._said.pop(0)
            self.pipeline.status(level, event, message, **extra)

    def _reset_point(self) -> None:
        """The operating point a (new) source starts at: the configured excitation, output off."""
        s = self.cfg["source"]
        self.limits = Limits(self.source.fs_hz, float(getattr(self.source, "max_current_a", 0.0) or 0.0))
        self.point = OperatingPoint(s["frequency_hz"], s["current_pp_a"], 0.0)

    # --- life cycle ------------------------------------------------------------------------------
    def start(self) -> "BenchService":
        from ..acquisition.zenoh_bus import ZenohBus

        c = self.cfg
        try:
            if c["recording"]["enabled"]:
                check_log_dir(self.log_dir, c.source)
                self.log.start()
            if c["zenoh"]["enabled"]:
                self.bus = ZenohBus(c["daemon"]["bench"], None if self.session else zenoh_config(c),
                                    on_command=self.command, config_provider=c.as_dict,
                                    health_provider=self.health, session=self.session,
                                    per_channel=c["zenoh"]["raw_per_channel"]).open()
            if c["foxglove"]["enabled"]:  # a taken port: ConfigError naming [foxglove] port
                f = c["foxglove"]
                self.foxglove = FoxgloveLive(f["host"], f["port"], name=c["daemon"]["bench"],
                                             channels=list(self.source.channels), fs_hz=self.source.fs_hz,
                                             plot_hz=f["plot_hz"], where=f"{c.source} [foxglove]").start()
            self._start_pipeline()
        except BaseException:
            self.stop()
            raise
        self.state = "running"
        if self.log.fault:
            self._log_failed(None)
        else:
            where = str(self.recorder.paths[-1]) if self.recorder is not None else "nowhere (recording disabled)"
            self._status("info", "log", f"logging to {where}; folder {self.log_dir}", log_dir=str(self.log_dir),
                         idle_raw=c["recording"]["idle_raw"])
        if c["sweep"]["autostart"]:
            self.command("start_sweep", {})
        return self

    def _metadata(self) -> dict:
        meta = {"recording": self.source.metadata(), "config": self.cfg.as_dict()}
        rig = getattr(getattr(self.source, "rig", None), "preset", None)
        if rig:
            meta["rig"] = {k: v for k, v in rig.items() if not k.startswith("_")}
        return meta

    def _start_pipeline(self, tripped: str = "") -> None:
        from ..acquisition.pipeline import Pipeline
        from ..acquisition.stages import WindowEstimator

        c = self.cfg
        e = c["estimation"]
        comp = _load_compensator(c["compensator"], self.source) if c["compensator"]["enabled"] else None
        if comp is not None and tripped:
            comp.tripped = tripped  # a fault does not clear it: only a reload does
        est = WindowEstimator(self.source.fs_hz, self.source.metadata(), periods=e["periods"],
                              hop_periods=e["hop_periods"], min_hop_s=e["min_hop_s"],
                              settle_periods=e["settle_periods"], max_fs_hz=e["max_fs_hz"],
                              keep_windows=bool(comp and comp.wants_windows)) if e["enabled"] else None
        self.pipeline = Pipeline(self.source, estimator=est, recorder=self.recorder, bus=self.bus, compensator=comp,
                                 ring_seconds=c["source"]["ring_seconds"], stats_interval_s=c["daemon"]["stats_interval_s"],
                                 publish_raw=c["zenoh"]["publish_raw"], on_log_error=self._log_failed,
                                 epoch_ns=self.log.epoch_ns)
        self.pipeline.listeners.append(self._count)
        if self.foxglove is not None:  # the same server across restarts: its clients stay
            self.foxglove.attach(self.pipeline)
        self.pipeline.start()

    def _count(self, topic: str, obj: dict) -> None:
        if topic == "/estimate":
            self.estimates += 1
            if obj.get("error"):
                self.last_error = str(obj["error"])

    def stop(self, timeout_s: float = 3.0) -> list[Path]:
        """Output off first, then the pipeline drains, the log is finished, zenoh is closed; every
        wait bounded (the daemon's SIGTERM ends it within STOP_S)."""
        if self.state == "stopped":  # a reload that failed stopped it already: nothing is open
            return self.log.finish()
        self.state = "stopping"
        self._sweep_stop.set()
        if hasattr(self.source, "set_output"):
            self.source.set_output(False)
        if self._sweep is not None:
            self._sweep.join(timeout=1.0)
        if self.pipeline is not None:
            self.pipeline.status("info", "stopping", "output off, finishing the log")
            self.pipeline.stop(timeout_s)
        self.source.close()
        paths = self.log.finish()
        if self.bus is not None:
            self.bus.close()
        if self.foxglove is not None:
            self.foxglove.close()
        self.state = "stopped"
        return paths

    # --- faults ----------------------------------------------------------------------------------
    def recover(self, timeout_s: float = 10.0) -> bool:
        """If a pipeline stage failed: output off, the fault published and logged, the source and
        the pipeline started again (output off) in a new log part.  Returns whether it did; raises
        :class:`TooManyFaults` when faults come too quickly, or what opening the source raises
        when it cannot be opened again."""
        from ..formats.mcaplog.schemas import STATUS

        p = self.pipeline
        if p is None or p.error is None or self.state not in ("running", "sweeping"):
            return False
        self.state = "recovering"
        err = p.error
        message = f"{type(err).__name__}: {err}"
        self._sweep_stop.set()
        self.source.close()  # output off before anything else (the drivers switch it off first)
        p.stop(timeout_s)
        if self._sweep is not None:
            self._sweep.join(timeout=2.0)
        now = time.monotonic()
        self.last_fault = message
        if caused_by_command(err):
            self.trips += 1
            self.tripped = (f"the excitation tripped the bench at {time.strftime('%H:%M:%S')} ({message}); check the "
                            "excitation, then send clear_fault")
        else:
            self.faults.append((now, message))
        recent = sum(1 for t, _ in self.faults if now - t <= FAULT_WINDOW_S)
        fault = {"t_ns": time.time_ns(), "level": "error", "event": "fault", "faults": len(self.faults),
                 "trips": self.trips, "by_command": bool(self.tripped),
                 "message": f"{message}; output switched off, restarting the source and pipeline"}
        log.error("fault: %s", fault["message"])
        if self.bus is not None:
            self.bus.publish("status", fault)
        tripped = str(getattr(p.compensator, "tripped", "") or "")
        self.log.add_status(STATUS, fault)
        self.log.rotate()
        if recent > MAX_FAULTS:
            raise TooManyFaults(f"{recent} faults within {FAULT_WINDOW_S:g} s, giving up; the last: {message}") from err
        self.source = build_source(self.cfg, clear_faults=True)
        self._reset_point()
        self._start_pipeline(tripped)
        self.state = "running"
        self.pipeline.status("warning", "restarted", f"after a fault ({message}); output off", fault=message,
                             faults=len(self.faults))
        return True

    def housekeeping(self) -> None:
        """Every turn of the daemon's loop: the log's retention, logging resumed (output still off)
        once a full folder has room again, and the count of refused commands not logged one by one."""
        self.log.housekeeping()
        if self.bus is not None:
            self.bus.report_held_refusals()
        if self.log.fault and self.pipeline is not None and self.state in ("running", "sweeping"):
            rec = self.log.resume()
            if rec is not None:
                self.pipeline.attach_recorder(rec)

    def _log_failed(self, err) -> None:
        """The disk refused a write (the record stage let the log go; ``err`` None: at start): the
        output goes off before anything else, a sweep stops, and ``output on`` is refused until
        logging resumes by itself; zenoh, the estimates and the commands go on."""
        if hasattr(self.source, "set_output"):
            self.source.set_output(False)
        self._sweep_stop.set()
        if err is not None:
            self.log.failed(err)
        if self.pipeline is not None:
            self.pipeline.status("error", "logging_paused", f"{self.log.fault}; output off until logging resumes",
                                 log_dir=str(self.log_dir))

    # --- commands (zenoh cmd/<verb>) -------------------------------------------------------------
    def _controllable(self):
        from ..acquisition.sources import Controllable

        if not isinstance(self.source, Controllable):
            raise CommandRefused(f"source {self.source.name!r} takes no commands")
        return self.source

    def _tripped(self) -> str:
        """Why the compensator switched the output off, or ''."""
        return str(getattr(getattr(self.pipeline, "compensator", None), "tripped", "") or "")

    def why_output_off(self) -> str:
        """Why ``output on`` and ``start_sweep`` are refused now, and how to clear it ('' : they are not)."""
        if self._tripped():
            return (f"the compensator switched the output off ({self._tripped()}); reload the configuration "
                    "(SIGHUP) to start again")
        if self.log.fault:
            return (f"the log cannot be written ({self.log.fault}); logging resumes by itself once the folder has room "
                    "(free space there, or let [recording] max_total_gib retention free it)")
        return self.tripped

    def _apply(self, src, point: OperatingPoint, who: str) -> None:
        """Put ``point`` on the amplifier, checked as it will really be played (offset included);
        the caller holds ``_lock``, so no other command moves the point in between."""
        check_current(who, point, self.limits)
        src.set_excitation(point.frequency_hz, point.current_pp_a, point.offset_a)
        self.point = point

    def command(self, verb: str, args: dict) -> dict:
        """Run a command; a refusal (answered ``ok: false``) says why: a ConfigError for what the
        command asks (checked before anything is applied), a CommandRefused for what the bench
        cannot do now (not running, a sweep running, the output switched off by the compensator)."""
        if self.pipeline is None or self.state not in ("running", "sweeping"):
            raise CommandRefused(f"bench is {self.state}; try again when it is running")
        src = self._controllable()
        with self._lock:
            ok, point = check_command(verb, args, self.limits, self.point, self.cfg["sweep"],
                                      sweep_point_periods(self.cfg))
            if (verb == "start_sweep" or verb == "output" and ok["on"]) and (why := self.why_output_off()):
                raise CommandRefused(f"{verb}: refused, {why}")
            if verb == "clear_fault":
                cleared, self.tripped = self.tripped, ""
                if cleared:
                    self.pipeline.status("info", "fault_cleared", f"cleared: {cleared}")
                return {"cleared": cleared or None, "still_refused": self.why_output_off() or None}
            if verb == "set_excitation":
                self._apply(src, point, "set_excitation")
                return {"applied": ok}
            if verb == "output":
                src.set_output(ok["on"])
                return {"output_on": ok["on"]}
            if verb == "stop_sweep":
                self._sweep_stop.set()
                sweep = self._sweep
            elif self._sweep is not None and self._sweep.is_alive():
                raise CommandRefused("start_sweep: a sweep is running; stop_sweep first")
            else:
                self._sweep_stop = threading.Event()
                self._sweep = threading.Thread(target=self._run_sweep, args=(ok, self._sweep_stop), name="sweep",
                                               daemon=True)
                self._sweep.start()
                return {"points": len(ok["frequencies_hz"]), "duration_s": len(ok["frequencies_hz"]) * ok["dwell_s"]}
        if sweep is not None:  # its last act (output off) must not come after the next command
            sweep.join(timeout=5.0)
        src.set_output(False)
        return {"stopped": True}

    def _run_sweep(self, sweep: dict, stop: threading.Event) -> None:
        src, p = self.source, self.pipeline
        freqs, ipp, dwell = sweep["frequencies_hz"], sweep["current_pp_a"], sweep["dwell_s"]
        self.state = "sweeping"
        p.status("info", "sweep_started", f"{len(freqs)} points at {ipp:g} A-pp, {dwell:g} s each")
        try:
            for k, f in enumerate(freqs):
                if why := self.why_output_off():
                    p.status("warning", "sweep_stopped", f"stopped at point {k}: {why}")
                    return
                with self._lock:
                    if stop.is_set():
                        break
                    try:  # the point as it will be played: with the offset set_excitation left
                        self._apply(src, replace(self.point, frequency_hz=f, current_pp_a=ipp), f"start_sweep point {k}")
                        src.set_output(True)
                    except (ConfigError, CommandRefused) as err:  # refused, or the source busy with a flood
                        src.set_output(False)
                        p.status("error", "sweep_stopped", f"stopped before point {k} ({f:g} Hz): {err}; output off",
                                 point=k, frequency_hz=f, current_pp_a=ipp, offset_a=self.point.offset_a)
                        return
                    reached = p.after_samples(round(dwell * src.fs_hz))  # from the command on
                p.status("info", "sweep_point", f"{f:g} Hz, {ipp:g} A-pp", point=k, frequency_hz=f, current_pp_a=ipp)
                fault = self._dwell(p, reached, stop)
                if fault is not None:
                    if fault:
                        src.set_output(False)  # a fault: output off before anything else
                    p.status("error" if fault else "info", "sweep_stopped",
                             f"stopped at point {k}" + (f": {fault}; output off" if fault else ""))
                    return
            else:
                p.status("info", "sweep_done", f"{len(freqs)} points")
        finally:
            src.set_output(False)
            if self.state == "sweeping":
                self.state = "running"

    @staticmethod
    def _dwell(p, reached: threading.Event, stop: threading.Event) -> str | None:
        """Wait until the source has given the point's samples (``reached``): the dwell runs on
        the source's own sample clock, so a bench slower than real time still gives each point
        its samples.  None when it did; '' when ``stop`` was set; why, when the source ended or
        gave no sample for ``DWELL_STALL_S``."""
        last, since = p.position, time.monotonic()
        while not reached.wait(DWELL_POLL_S):
            if stop.is_set():
                return ""
            if p.error is not None or p.ring.closed:
                return f"the source ended at sample {p.position} before the point's dwell" + (
                    f" ({type(p.error).__name__}: {p.error})" if p.error is not None else "")
            if p.position != last:
                last, since = p.position, time.monotonic()
            elif time.monotonic() - since > DWELL_STALL_S:
                return f"no sample from the source for {DWELL_STALL_S:g} s (at sample {last})"
        return None

    def health(self) -> dict:
        p = self.pipeline
        z = self.cfg["zenoh"]
        return {"bench": self.cfg["daemon"]["bench"], "state": self.state, "version": __version__, "pid": os.getpid(),
                "uptime_s": time.monotonic() - self.started, "source": self.source.name,
                "recording": self.source.metadata(), "channels": list(self.source.channels),
                "listen": list(z["listen"]) if z["enabled"] else [], "config": self.cfg.source,
                "log_dir": str(self.log_dir), **self.log.health(), "idle_raw": self.cfg["recording"]["idle_raw"],
                "limits": {"max_current_a": self.limits.max_current_a,
                           "frequency_hz": [MIN_FREQUENCY_HZ, self.limits.max_frequency_hz]},
                "samples": p.stats["source"].samples if p else 0, "estimates": self.estimates,
                "commands_refused": self.bus.refused if self.bus is not None else 0,
                "faults": len(self.faults), "trips": self.trips, "last_fault": self.last_fault,
                "output_refused": self.why_output_off() or None,
                "pipeline_error": repr(p.error) if p and p.error else None, "last_estimate_error": self.last_error,
                "foxglove": self.foxglove.health() if self.foxglove is not None else None,
                **self.excitation()}

    def excitation(self) -> dict:
        """What the generator plays: ``output_on``, ``frequency_hz``, ``current_pp_a``, ``offset_a``,
        as the last block the pipeline received was played (``as_of`` "played"); before any block,
        or from a source whose blocks carry no operating point, the last excitation commanded, the
        output's state unknown (None)."""
        meta = self.pipeline.last_meta if self.pipeline is not None else {}
        played = bool(meta)
        point = OperatingPoint.from_meta(meta, default=self.point)
        return {"output_on": point.output_on if "output_on" in meta else None,
                "frequency_hz": point.frequency_hz, "current_pp_a": point.current_pp_a, "offset_a": point.offset_a,
                "as_of": "played" if played else "commanded"}
