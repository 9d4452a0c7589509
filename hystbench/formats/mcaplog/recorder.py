"""The MCAP recorder: one log per session, small chunks, rotated by size or time.

Life cycle as mcap's own writer, plus a context manager: ``start()`` -> ``add_block`` /
``add_message`` ... -> ``finish()``.  Crash safety comes from the chunking: a chunk is closed and
handed to the OS at least every ``flush_interval_s`` (and whenever it reaches ``chunk_size``), so
after a ``kill -9`` everything but the open chunk is on disk and ``hystbench recover`` salvages it.
Each part of a rotated log starts with the same schemas and metadata, so each stands alone.

Raw blocks recorded while the output is off (block meta ``output_on`` = 0) follow ``idle_raw``:
``"full"`` keeps them all, ``"decimated"`` keeps a snapshot of ``IDLE_SNAPSHOT_S`` in every
``IDLE_EVERY_S`` of sample time (offsets, noise floor and pickup at full bandwidth, ~1 % of the
bytes), ``"off"`` none; JSON messages (estimates, status, stats) are always kept.

A write the disk refuses (full, an I/O error, remounted read-only) raises :class:`LogWriteError`
naming the part, its folder and the free space there; the recorder is then closed (what was
flushed stays readable, ``hystbench recover`` salvages it) and a new one may be started once space
is back.  A part that cannot even be started is removed, so a full disk gathers no empty parts.
``on_size(path, bytes)`` is told the open part's size as it grows (every half chunk), so retention
can keep a folder's cap before the part grows past it.
"""

from __future__ import annotations

import errno
import json
import os
import shutil
import time
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, Callable, Mapping

from ... import __version__
from ...blocks import BlockFlags, SampleBlock
from ...errors import LogWriteError, RecordingError
from ...messages import json_bytes
from ..raw_block import encode_json
from .schemas import RAW, SCHEMAS, TOPICS, schema_bytes

__all__ = ["McapRecorder", "COMPRESSIONS", "IDLE_RAW", "IDLE_EVERY_S", "IDLE_SNAPSHOT_S", "free_bytes",
           "write_error"]

COMPRESSIONS = ("zstd", "lz4", "none")
PROFILE = "hystbench"
IDLE_RAW = ("off", "decimated", "full")
#: ``idle_raw = "decimated"``: the first IDLE_SNAPSHOT_S of every IDLE_EVERY_S (of sample time,
#: aligned on sample index 0, so replays cut the same snapshots).
IDLE_EVERY_S = 1.0
IDLE_SNAPSHOT_S = 0.01


def free_bytes(folder: str | Path) -> int | None:
    """Bytes free for this process in ``folder`` (or its nearest existing parent); None if unknown."""
    p = Path(folder)
    while not p.exists() and p != p.parent:
        p = p.parent
    try:
        return shutil.disk_usage(p).free
    except OSError:
        return None


def write_error(path: Path, err: OSError, doing: str) -> LogWriteError:
    """``err`` as the error a bench engineer can act on: the part, the folder, its free space."""
    free = free_bytes(path.parent)
    room = f"{free / 2**20:.1f} MiB free" if free is not None else "free space unknown"
    why = err.strerror or errno.errorcode.get(err.errno or 0, "") or str(err)
    return LogWriteError(f"{path}: cannot {doing}: {why} (folder {path.parent}, {room})", errno=err.errno,
                         folder=str(path.parent))


def _metadata_record(obj: Mapping[str, Any]) -> dict[str, str]:
    """MCAP metadata is str -> str: the whole object as JSON under ``json`` (what readers use),
    beside each top-level key as display text (what Foxglove shows)."""
    out = {"json": json.dumps(obj, default=str)}
    for k, v in obj.items():
        out[str(k)] = v if isinstance(v, str) else json.dumps(v, default=str)
    return out


class McapRecorder:
    """Writes one session's log to ``path`` (or, rotated, ``STEM-0001.mcap``, ``STEM-0002.mcap``...).

    ``metadata`` maps a record name (``recording``, ``config``, ``rig``...) to a JSON-able dict,
    written into every part; ``epoch_ns`` is the wall-clock time of sample index 0, so raw
    blocks get ``log_time = epoch_ns + first_index / fs``.
    """

    def __init__(self, path: str | Path, *, metadata: Mapping[str, Mapping[str, Any]] | None = None,
                 compression: str = "zstd", chunk_size: int = 256 * 1024, flush_interval_s: float = 0.5,
                 rotate_bytes: int | None = None, rotate_s: float | None = None, epoch_ns: int | None = None,
                 units: Mapping[str, str] | None = None, overwrite: bool = False, idle_raw: str = "full",
                 on_size: Callable[[Path, int], None] | None = None) -> None:
        if compression not in COMPRESSIONS:
            raise RecordingError(f"{path}: compression must be one of {', '.join(COMPRESSIONS)}, got {compression!r}")
        if idle_raw not in IDLE_RAW:
            raise RecordingError(f"{path}: idle_raw must be one of {', '.join(IDLE_RAW)}, got {idle_raw!r}")
        for name, v in (("rotate_bytes", rotate_bytes), ("rotate_s", rotate_s), ("flush_interval_s", flush_interval_s)):
            if v is not None and not v > 0:
                raise RecordingError(f"{path}: {name} must be > 0, got {v!r}")
        self.path = Path(path)
        self.metadata = {k: dict(v) for k, v in (metadata or {}).items()}
        self.compression = compression
        self.chunk_size = int(chunk_size)
        self.flush_interval_s = float(flush_interval_s)
        self.rotate_bytes, self.rotate_s = rotate_bytes, rotate_s
        self.epoch_ns = time.time_ns() if epoch_ns is None else int(epoch_ns)
        self.units = dict(units or {})
        self.overwrite = overwrite
        self.idle_raw = idle_raw
        self.on_size = on_size
        self.idle_samples_skipped = 0  # raw samples with the output off not written (idle_raw)
        self.paths: list[Path] = []
        self.messages = 0
        self.bytes_in = 0  # message bytes handed to the writer (before compression)
        self._size_checked_in = 0  # bytes_in when the part's size was last asked
        self._writer = None
        self._fh = None
        self._channel_ids: dict[str, int] = {}
        self._part_started = 0.0
        self._last_flush = 0.0
        #: End sample index of the last raw block handed to the writer, and of the last one on
        #: disk (in the OS's hands: a kill -9 of this process loses none of it).
        self.raw_end_added = self.raw_end_flushed = 0

    # --- life cycle ------------------------------------------------------------------------------
    def _part_path(self, part: int) -> Path:
        if self.rotate_bytes is None and self.rotate_s is None:
            return self.path
        stem = self.path.with_suffix("") if self.path.suffix == ".mcap" else self.path
        return stem.with_name(f"{stem.name}-{part:04d}.mcap")

    def start(self) -> "McapRecorder":
        if self._writer is not None:
            raise RecordingError(f"{self.path}: recorder already started")
        self._open_part()
        return self

    def _open_part(self) -> None:
        path = self._part_path(len(self.paths) + 1)
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            self._fh = open(path, "wb" if self.overwrite else "xb")
        except FileExistsError as err:
            raise RecordingError(f"{path}: already exists; choose another name, or give --overwrite (overwrite=True from "
                                 "Python) to replace it") from err
        except OSError as err:
            raise write_error(path, err, "create the log") from err
        try:
            self._start_part(path)
        except OSError as err:  # a full disk: no empty part left behind
            self.abandon()
            path.unlink(missing_ok=True)
            raise write_error(path, err, "start the log") from err

    def _start_part(self, path: Path) -> None:
        from mcap.writer import CompressionType, Writer

        comp = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4, "none": CompressionType.NONE}
        w = Writer(self._fh, chunk_size=self.chunk_size, compression=comp[self.compression])
        w.start(profile=PROFILE, library=f"hystbench {__version__}")
        self._channel_ids = {}
        for topic in TOPICS:
            name, _ = SCHEMAS[topic]
            sid = w.register_schema(name=name, encoding="jsonschema", data=schema_bytes(topic))
            self._channel_ids[topic] = w.register_channel(topic=topic, message_encoding="json", schema_id=sid)
        part = len(self.paths) + 1
        session = {"software": f"hystbench {__version__}", "created_utc": datetime.now(timezone.utc).isoformat(),
                   "epoch_ns": self.epoch_ns, "part": part,
                   "previous_part": self.paths[-1].name if self.paths else ""}
        w.add_metadata("hystbench", _metadata_record(session))
        for name, obj in self.metadata.items():
            w.add_metadata(name, _metadata_record(obj))
        w.flush()  # schemas and channels on disk before any data
        self._fh.flush()
        self._writer = w
        self.paths.append(path)
        self._part_started = self._last_flush = time.monotonic()
        self._size_checked_in = self.bytes_in

    def rotate(self) -> Path:
        """Finish the open part and start the next one (e.g. after a fault: one part per run of
        the pipeline); returns the new part's path."""
        if self._writer is None:
            raise RecordingError(f"{self.path}: recorder not started (or already finished)")
        if self.rotate_bytes is None and self.rotate_s is None:
            raise RecordingError(f"{self.path}: a log without rotation has one part; give rotate_bytes or rotate_s")
        self.finish()
        self._open_part()
        return self.paths[-1]

    def finish(self) -> list[Path]:
        """Close the log (summary, indexes, footer); returns the parts written.  Idempotent.  A disk
        that refuses the summary leaves the part without it (recover salvages it) and raises
        :class:`LogWriteError`; the recorder is closed either way."""
        if self._writer is not None:
            w, fh = self._writer, self._fh
            self._writer = self._fh = None
            try:
                w.finish()
                fh.flush()
                os.fsync(fh.fileno())
            except OSError as err:
                raise write_error(self.paths[-1], err, "finish the log") from err
            finally:
                try:
                    fh.close()  # flushes what Python still buffers: may fail again on a full disk
                except OSError:
                    pass
        return list(self.paths)

    def abandon(self) -> None:
        """Close the open part as it stands, without a summary (after a write error: writing one
        would fail too); what was flushed stays readable."""
        fh, self._writer, self._fh = self._fh, None, None
        if fh is not None:
            try:
                fh.close()
            except OSError:
                pass

    def __enter__(self) -> "McapRecorder":
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.finish()

    # --- messages --------------------------------------------------------------------------------
    def add_block(self, block: SampleBlock) -> None:
        """One raw block (every channel); with the output off, what ``idle_raw`` keeps of it."""
        if self.idle_raw != "full" and block.point is not None and not block.point.output_on:
            for piece in self._idle_pieces(block):
                self._add(RAW, encode_json(piece, self.units), self.epoch_ns + piece.t0_ns)
            return
        self._add(RAW, encode_json(block, self.units), self.epoch_ns + block.t0_ns)
        self.raw_end_added = block.end_index

    def _idle_pieces(self, block: SampleBlock) -> list[SampleBlock]:
        """The parts of an idle block inside the decimation's snapshots (none with ``"off"``)."""
        every = max(1, round(IDLE_EVERY_S * block.fs_hz))
        length = max(1, round(IDLE_SNAPSHOT_S * block.fs_hz))
        a, b = block.first_index, block.end_index
        out = []
        if self.idle_raw == "decimated":
            for k in range(a // every, (b - 1) // every + 1):
                lo, hi = max(a, k * every), min(b, k * every + length)
                if lo < hi:
                    first = lo == a
                    out.append(SampleBlock(lo, block.fs_hz, {c: x[lo - a:hi - a] for c, x in block.channels.items()},
                                           flags=block.flags if first else block.flags & ~BlockFlags.GAP,
                                           gap_samples=block.gap_samples if first else 0, meta=block.meta))
        self.idle_samples_skipped += block.n - sum(p.n for p in out)
        return out

    def add_message(self, topic: str, obj: Mapping[str, Any], log_time_ns: int | None = None) -> None:
        """A JSON message on one of :data:`TOPICS` (``/estimate``, ``/compensator``, ``/status``...)."""
        if topic not in self._channel_ids and self._writer is not None:
            raise RecordingError(f"{self.path}: unknown topic {topic!r}; known: {', '.join(TOPICS)}")
        t = time.time_ns() if log_time_ns is None else int(log_time_ns)
        self._add(topic, json_bytes(obj), t)

    def index_time_ns(self, index: int, fs_hz: float) -> int:
        """The log time of sample ``index`` (what raw blocks and estimates are stamped with)."""
        return self.epoch_ns + round(index * 1e9 / fs_hz)

    def _add(self, topic: str, data: bytes, log_time_ns: int) -> None:
        if self._writer is None:
            raise RecordingError(f"{self.path}: recorder not started (or already finished)")
        now = time.monotonic()
        try:
            if self._should_rotate(now):
                self.finish()
                self._open_part()
            self._writer.add_message(self._channel_ids[topic], log_time=log_time_ns, data=data,
                                     publish_time=time.time_ns(), sequence=self.messages)
        except OSError as err:
            self.abandon()
            raise write_error(self.paths[-1], err, "write the log") from err
        self.messages += 1
        self.bytes_in += len(data)
        self.tick(now)

    def tick(self, now: float | None = None) -> None:
        """Close the open chunk if it is older than ``flush_interval_s`` (call this when idle, too)."""
        now = time.monotonic() if now is None else now
        if self._writer is not None and now - self._last_flush >= self.flush_interval_s:
            try:
                self._writer.flush()
                self._fh.flush()  # in the OS's hands: what a kill -9 keeps, and where a full disk shows
                deleted = os.fstat(self._fh.fileno()).st_nlink == 0
            except OSError as err:
                self.abandon()
                raise write_error(self.paths[-1], err, "write the log") from err
            if deleted:  # written on, it would be lost whole at close, and say nothing until then
                path = self.paths[-1]
                self.abandon()
                raise LogWriteError(f"{path}: the open log part was deleted (its folder {path.parent} removed?); what "
                                    "it held is gone, nothing more is written there", errno=errno.ENOENT,
                                    folder=str(path.parent))
            self._last_flush = now
            self.raw_end_flushed = self.raw_end_added

    def _should_rotate(self, now: float) -> bool:
        if self.rotate_s is not None and now - self._part_started >= self.rotate_s:
            return True
        if (self.rotate_bytes is None and self.on_size is None) or self._fh is None or \
                self.bytes_in - self._size_checked_in < self.chunk_size // 2:
            return False  # the part grows a chunk at a time: its size (a system call) is asked once one may be out
        self._size_checked_in = self.bytes_in
        size = self._fh.tell()
        if self.on_size is not None:
            self.on_size(self.paths[-1], size)
        return self.rotate_bytes is not None and size >= self.rotate_bytes

    @property
    def bytes_written(self) -> int:
        """Bytes in the finished parts still on disk and the open one (compressed, as on disk).  A
        finished part may go at any moment (retention deletes the oldest from the recorder's own
        thread while the stats ask from theirs): one that vanished counts 0, never an error, which
        took the whole pipeline down through its stats stage."""
        return sum(_size_on_disk(p) for p in self.paths[:-1]) + (self._fh.tell() if self._fh is not None else 0)


def _size_on_disk(path: Path) -> int:
    """A file's size, 0 when it is gone (stat, not exists-then-stat: nothing can vanish in between)."""
    try:
        return path.stat().st_size
    except FileNotFoundError:
        return 0
