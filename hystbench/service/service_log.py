"""The daemon's MCAP log as part of the service: its parts, its folder's cap, and what a full disk does.

A disk that refuses a write (full, an I/O error, remounted read-only) must not stop the bench
service, nor leave it hanging: the record stage lets the log go (:class:`~hystbench.acquisition.pipeline.Pipeline`),
:meth:`ServiceLog.failed` says why (the part, the folder, its free space) and the service switches
the output off and refuses ``output on`` while :attr:`ServiceLog.fault` is set.  Every turn of the
daemon's loop calls :meth:`ServiceLog.housekeeping`, which resumes logging in a new part by itself
once the folder has :data:`RESUME_FREE_BYTES` free again (retention may free it).

``[recording] max_total_gib`` is kept as the log grows, not once a minute: the recorder tells the
open part's size every half chunk (``on_size``), and once the finished parts and the open one come
within two chunks of the cap, the oldest parts go.  A part is at most a quarter of the cap, so
deleting whole finished parts always brings the folder back under it.
"""

from __future__ import annotations

import errno
import logging
import os
import tempfile
import time
from pathlib import Path
from typing import Any, Callable, Mapping

from ..errors import ConfigError, LogWriteError
from ..formats.mcaplog.recorder import McapRecorder, free_bytes
from .retention import apply_retention

__all__ = ["ServiceLog", "check_log_dir", "log_path", "RESUME_FREE_BYTES", "RETENTION_EVERY_S"]

log = logging.getLogger("hystbench.daemon")

#: Logging resumes once the folder has this much free: a few seconds of the fullest log (raw
#: samples at 100 kS/s, ``idle_raw = "full"``: about 1.6 MB/s), so it does not fail again at once.
RESUME_FREE_BYTES = 8 * 2**20
#: Age-based retention (``keep_days``) runs this often; the size cap is kept as the log grows.
RETENTION_EVERY_S = 60.0
#: Errors of the disk's state, which pass: at start the service waits for room and resumes.  Any
#: other (no permission, read-only, not a folder) is the configuration's: refused before the
#: service starts or a reload touches it.  While running, every write error pauses the log.
PASSING = frozenset({errno.ENOSPC, errno.EDQUOT, errno.EIO})


def log_path(folder: Path, bench: str) -> Path:
    """``<bench>-<start time>.mcap`` (parts ``...-0001.mcap``), made unique within the second."""
    stem = f"{bench}-{time.strftime('%Y%m%d-%H%M%S')}"
    k = 1
    while (folder / f"{stem}-0001.mcap").exists() or (folder / f"{stem}.mcap").exists():
        k += 1
        stem = f"{bench}-{time.strftime('%Y%m%d-%H%M%S')}.{k}"
    return folder / f"{stem}.mcap"


def check_log_dir(folder: str | Path, where: str) -> None:
    """Refuse a log folder this process cannot write in (ConfigError naming ``where``'s key), before
    anything runs; a folder that is only full now passes (the service waits for room)."""
    folder = Path(folder)
    try:
        folder.mkdir(parents=True, exist_ok=True)
        fd, probe = tempfile.mkstemp(prefix=".hystbench-probe-", dir=folder)
        os.close(fd)
        os.unlink(probe)
    except OSError as err:
        if err.errno in PASSING and folder.is_dir():
            return
        raise ConfigError(f"{where} [daemon] log_dir {folder}: cannot write there: {err.strerror}") from err


class ServiceLog:
    """The log of one configuration running: ``cfg`` the daemon config, ``metadata()`` what every
    part starts with, ``status(level, event, message, **extra)`` where its events are told."""

    def __init__(self, cfg: Any, metadata: Callable[[], Mapping[str, Any]],
                 status: Callable[..., None]) -> None:
        self.r = cfg["recording"]
        self.enabled = bool(self.r["enabled"])
        self.folder = Path(cfg["daemon"]["log_dir"])
        self.bench = cfg["daemon"]["bench"]
        self.metadata, self.status = metadata, status
        self.cap_bytes = float(self.r["max_total_gib"]) * 2**30
        self.chunk_bytes = int(self.r["chunk_kib"]) * 1024
        self.epoch_ns = time.time_ns()  # one clock for every part of this configuration's log
        self.recorder: McapRecorder | None = None
        self.parts: list[Path] = []  # every part this log wrote, oldest first
        self.fault = ""  # why logging is paused ('' : it is not)
        self.fault_errno: int | None = None
        self.deleted = 0
        self._finished_bytes = 0  # the bench's finished parts in the folder (since the last pass)
        self._open: tuple[Path | None, int] = (None, 0)  # the open part and its size when last told
        self._retention_t = -float("inf")

    # --- recorders -------------------------------------------------------------------------------
    def start(self) -> McapRecorder | None:
        """A started recorder in a new log (None when recording is off or the disk has no room:
        then :attr:`fault` says why and :meth:`housekeeping` tries again)."""
        if not self.enabled:
            return None
        r = self.r
        rotate = int(r["rotate_mib"] * 2**20)
        if self.cap_bytes:
            rotate = min(rotate, max(int(self.cap_bytes // 4), 2 * self.chunk_bytes))
        rec = McapRecorder(log_path(self.folder, self.bench), metadata=self.metadata(), compression=r["compression"],
                           chunk_size=self.chunk_bytes, flush_interval_s=r["flush_interval_s"],
                           idle_raw=r["idle_raw"], rotate_bytes=rotate, rotate_s=r["rotate_minutes"] * 60,
                           epoch_ns=self.epoch_ns, on_size=self._grew if self.cap_bytes else None)
        self._retention()  # room first, and the finished parts' total
        try:
            rec.start()
        except LogWriteError as err:  # the folder was checked (check_log_dir): this is the disk's state
            self._pause(err)
            return None
        self.recorder, self.fault, self.fault_errno = rec, "", None
        self.parts.append(rec.paths[-1])
        return rec

    def failed(self, err: LogWriteError) -> None:
        """The record stage let the recorder go after ``err``; logging pauses until there is room."""
        if self.recorder is not None:
            self.recorder.abandon()
            self._note_parts(self.recorder)
            self.recorder = None
        self._pause(err)

    def _pause(self, err: LogWriteError) -> None:
        self.fault, self.fault_errno = str(err), err.errno
        log.error("logging paused: %s", err)

    def resume(self) -> McapRecorder | None:
        """A new recorder if logging is paused and the folder has room again (else None)."""
        if not self.fault or not self.enabled:
            return None
        free = free_bytes(self.folder)
        if free is None or free < RESUME_FREE_BYTES:
            return None
        was = self.fault
        rec = self.start()
        if rec is not None:
            self.status("info", "log_resumed", f"logging again to {rec.paths[-1]} ({free / 2**20:.1f} MiB free in "
                        f"{self.folder}); it had stopped: {was}", log=str(rec.paths[-1]))
        return rec

    def rotate(self) -> None:
        """A new part (after a fault: one part per run of the pipeline)."""
        if self.recorder is None:
            return
        try:
            self.recorder.rotate()
        except LogWriteError as err:
            self.failed(err)
            return
        self._note_parts(self.recorder)

    def add_status(self, topic: str, obj: Mapping[str, Any]) -> None:
        """A message written now, outside the pipeline (the fault that ends a part)."""
        if self.recorder is None:
            return
        try:
            self.recorder.add_message(topic, obj, obj.get("t_ns"))
        except LogWriteError as err:
            self.failed(err)

    def finish(self) -> list[Path]:
        """Close the log; every part it wrote."""
        if self.recorder is not None:
            try:
                self.recorder.finish()
            except LogWriteError as err:
                log.error("the log's last part has no summary (recover salvages it): %s", err)
            self._note_parts(self.recorder)
            self.recorder = None
        return list(self.parts)

    def _note_parts(self, rec: McapRecorder) -> None:
        self.parts += [p for p in rec.paths if p not in self.parts]

    # --- the folder ------------------------------------------------------------------------------
    def housekeeping(self, now: float | None = None) -> None:
        """Every turn of the daemon's loop: age-based retention every RETENTION_EVERY_S; logging
        resumed once there is room (see :meth:`resume`, which the service attaches)."""
        now = time.monotonic() if now is None else now
        if self.fault or now - self._retention_t >= RETENTION_EVERY_S:  # paused: what it frees is the room waited for
            self._retention_t = now
            self._retention()

    def _retention(self) -> None:
        r = self.r
        if not self.enabled or not (r["keep_days"] or self.cap_bytes):
            return
        keep = self.recorder.paths[-1:] if self.recorder is not None else []
        try:
            rep = apply_retention(self.folder, self.bench, keep_days=r["keep_days"], max_total_bytes=self.cap_bytes,
                                  keep=keep, own=self.parts)
        except OSError as err:  # the folder itself unreadable: said, and tried again later
            self.status("warning", "retention", f"cannot list {self.folder}: {err.strerror}")
            return
        open_bytes = self._open[1] if keep and self._open[0] == keep[0] else 0
        self._finished_bytes = max(0, rep.kept_bytes - open_bytes)
        self.deleted += len(rep.deleted)
        if rep.deleted or rep.errors:
            self.status("warning" if rep.errors else "info", "retention",
                        rep.message() + ("; " + "; ".join(rep.errors) if rep.errors else ""),
                        deleted=[p.name for p in rep.deleted], deleted_bytes=rep.deleted_bytes)

    def _grew(self, part: Path, size: int) -> None:
        """The open part's size, from the record thread every half chunk: the cap is kept before
        the part grows past it (two chunks of room, as a chunk lands whole)."""
        last, last_size = self._open
        if last is not None and last != part:  # the recorder rotated: the last part is finished
            self._finished_bytes += last_size
        self._open = (part, size)
        if self._finished_bytes + size > self.cap_bytes - 2 * self.chunk_bytes:
            self._retention()

    def health(self) -> dict[str, Any]:
        rec = self.recorder
        return {"log": str(rec.paths[-1]) if rec is not None and rec.paths else None,
                "logging": "off" if not self.enabled else ("paused" if self.fault else "on"),
                "log_error": self.fault or None, "log_free_bytes": free_bytes(self.folder),
                "idle_samples_skipped": rec.idle_samples_skipped if rec else 0,
                "raw_flushed_to": rec.raw_end_flushed if rec else 0, "retention_deleted": self.deleted}
