"""Reading hystbench MCAP logs: messages, raw blocks, operating-point segments, replay.

A log of a whole session may hold several operating points (a sweep) and gaps; a *segment* is a
run of contiguous raw blocks with one :class:`~hystbench.messages.OperatingPoint` (block meta),
and :meth:`Segment.recording` gives one as an interchange-format :class:`Recording` with that
point in its sidecar.  Which samples of a segment the live estimator skipped as settling is the
analysis' business: :mod:`hystbench.analysis.log_recordings` gives a log's segments as the
estimator saw them (``hystbench estimate LOG.mcap``, ``export``).
A log that was not finished (the writer was killed) is refused with a pointer to ``recover``, a
file that is not MCAP as such.  Chunks are decoded by :mod:`.chunks` (sizes capped before any
decompression) and records longer than ``MAX_RECORD_BYTES`` are refused, so a damaged or hostile
log costs at most one bounded chunk of memory.
"""

from __future__ import annotations

import dataclasses
import io
import json
import os
import struct
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterable, Iterator

from ...blocks import BlockFlags, SampleBlock
from ...errors import RecordingError
from ...messages import UNKNOWN_POINT, OperatingPoint
from ..raw_block import decode
from ..recording import Recording, times_fit, with_point
from ..small_files import finite, shown
from .chunks import MAGIC, MAX_RECORD_BYTES, chunk_records
from .schemas import RAW

__all__ = ["LogMessage", "iter_log", "iter_blocks", "log_metadata", "estimation_settings", "segments", "McapSource",
           "Segment", "ESTIMATION_BOUNDS"]


@dataclass(frozen=True)
class LogMessage:
    """One message of a log as recorded (topic, log time, bytes): decoded only when asked (:meth:`json`)."""

    topic: str
    log_time_ns: int
    data: bytes

    def json(self) -> Any:
        return json.loads(self.data)


def _open(path: Path):
    try:
        return open(path, "rb")
    except OSError as err:
        raise RecordingError(f"{path}: cannot open: {err.strerror}") from err


def _damaged(path: Path, err: Exception) -> RecordingError:
    return RecordingError(f"{path}: not a complete MCAP log ({type(err).__name__}: {err}); if the writer "
                          f"was killed, `hystbench recover {path}` salvages its complete chunks")


def check_magic(fh: Any, path: Path) -> int:
    """The size of the open file ``fh``, once it is known to start as an MCAP file does; else a
    :class:`RecordingError` that says it is not one (``recover`` cannot help then)."""
    size = os.fstat(fh.fileno()).st_size
    head = fh.read(len(MAGIC))
    fh.seek(0)
    if head != MAGIC:
        what = "an empty file" if not head else f"{size} bytes starting {head[:8]!r}"
        raise RecordingError(f"{path}: not an MCAP file (bad magic: {what}, where an MCAP log "
                             f"starts with {MAGIC!r})")
    return size


def _records(fh: Any) -> Iterator[Any]:
    """The top-level records of the data section, chunks as :class:`mcap.records.Chunk` (not
    decompressed here), up to and including the DataEnd record."""
    from mcap.records import DataEnd
    from mcap.stream_reader import StreamReader

    for record in StreamReader(fh, emit_chunks=True, record_size_limit=MAX_RECORD_BYTES).records:
        yield record
        if isinstance(record, DataEnd):
            return


def iter_log(path: str | Path, topics: Iterable[str] | None = None) -> Iterator[LogMessage]:
    """Messages in file order (which is time order for a hystbench log)."""
    from mcap.reader import SeekingReader
    from mcap.records import Channel, Chunk, Message

    path = Path(path)
    wanted = None if topics is None else set(topics)
    with _open(path) as fh:
        check_magic(fh, path)
        try:
            # an unfinished log is refused before any message is given, not where it is cut
            if SeekingReader(fh, record_size_limit=MAX_RECORD_BYTES).get_summary() is None:
                raise ValueError("no summary section")
            fh.seek(0)
            topic_of: dict[int, str] = {}
            for record in _records(fh):
                # CRCs unchecked, as mcap's seeking reader does by default: a replay meets damage
                # where a message fails to decode (``recover`` checks them)
                for rec in chunk_records(record, check_crc=False) if isinstance(record, Chunk) else (record,):
                    if isinstance(rec, Channel):
                        topic_of[rec.id] = rec.topic
                    elif isinstance(rec, Message):
                        if rec.channel_id not in topic_of:
                            raise ValueError(f"a message on channel {rec.channel_id}, which no record defines")
                        if wanted is None or topic_of[rec.channel_id] in wanted:
                            yield LogMessage(topic_of[rec.channel_id], rec.log_time, rec.data)
        except Exception as err:  # the mcap reader raises many kinds on a damaged file (chunks: RecordingError)
            raise _damaged(path, err) from err


def _metadata_at(fh: Any, offset: int, size: int) -> Any:
    """The metadata record a summary's index points at, read without trusting the index further."""
    from mcap.data_stream import ReadDataStream
    from mcap.opcode import Opcode
    from mcap.records import Metadata

    fh.seek(offset)
    head = fh.read(9)
    if len(head) < 9:
        raise ValueError(f"metadata index points past the end of the file ({offset})")
    opcode, length = struct.unpack("<BQ", head)
    if opcode != Opcode.METADATA or length > min(MAX_RECORD_BYTES, size - offset - 9):
        raise ValueError(f"metadata index points at offset {offset}, which holds no metadata record")
    return Metadata.read(ReadDataStream(io.BytesIO(fh.read(length))))


def log_metadata(path: str | Path) -> dict[str, dict]:
    """Metadata records by name, each the JSON object it was written from."""
    from mcap.reader import SeekingReader
    from mcap.records import Metadata

    path = Path(path)
    out: dict[str, dict] = {}
    with _open(path) as fh:
        size = check_magic(fh, path)
        try:
            summary = SeekingReader(fh, record_size_limit=MAX_RECORD_BYTES).get_summary()
            if summary is not None:
                found = [_metadata_at(fh, ix.offset, size) for ix in summary.metadata_indexes]
            else:  # no index: walk the data section (chunks are skipped, not decompressed)
                fh.seek(0)
                found = [r for r in _records(fh) if isinstance(r, Metadata)]
            for rec in found:
                text = rec.metadata.get("json")
                out[rec.name] = json.loads(text) if text is not None else dict(rec.metadata)
        except Exception as err:  # the mcap reader raises many kinds on a damaged file
            raise _damaged(path, err) from err
    for name, value in out.items():  # what a reader of the log takes as a table: a list there was a traceback
        if not isinstance(value, dict):
            raise RecordingError(f"{path}: metadata record {name!r} must be a JSON object, got {type(value).__name__}")
    config = out.get("config", {})
    if "estimation" in config and not isinstance(config["estimation"], dict):
        raise RecordingError(f"{path}: metadata record 'config': 'estimation' must be a JSON object, "
                             f"got {type(config['estimation']).__name__}")
    return out


#: The estimation settings a log records (``config.estimation``), each a finite number in
#: (lower, 1e9]: periods and seconds far beyond any session, small enough that a count of samples
#: stays an integer (a settle_s of 1e308 overflowed one).  ``periods`` >= 2 as the estimator asks.
ESTIMATION_BOUNDS: dict[str, tuple[float, bool]] = {  # key -> (lower bound, bound included)
    "periods": (2.0, True), "hop_periods": (0.0, False), "min_hop_s": (0.0, True), "settle_periods": (0.0, True),
    "settle_s": (0.0, True), "max_fs_hz": (0.0, False)}


def estimation_settings(meta: dict[str, dict], path: str | Path) -> dict[str, float]:
    """The estimation settings a log was recorded with (:func:`log_metadata`'s ``config.estimation``),
    checked: what a replay estimates with, and what an offline reader skips as settling (a bad one
    named, not a traceback in the replay or a quiet default in an export)."""
    given = (meta.get("config") or {}).get("estimation") or {}
    out = {}
    for key, (low, included) in ESTIMATION_BOUNDS.items():
        if key not in given:
            continue
        v = given[key]
        ok = isinstance(v, (int, float)) and not isinstance(v, bool) and finite(v) and v <= 1e9 and (
            v >= low if included else v > low)
        if not ok:
            raise RecordingError(f"{path}: metadata record 'config': estimation.{key} must be a number in "
                                 f"{'[' if included else '('}{low:g}, 1e9], got {shown(v)}")
        out[key] = float(v)
    return out


def iter_blocks(path: str | Path) -> Iterator[SampleBlock]:
    """The raw sample blocks, in order."""
    path = Path(path)
    for k, m in enumerate(iter_log(path, [RAW])):
        yield decode(m.data, f"{path}: raw message {k}")


def _point(block: SampleBlock) -> OperatingPoint:
    return UNKNOWN_POINT if block.point is None else block.point


@dataclass
class Segment:
    """Contiguous blocks at one operating point; ``transient``: the settling after its start."""

    blocks: list[SampleBlock]
    transient: bool = False

    @property
    def first_index(self) -> int:
        return self.blocks[0].first_index

    @property
    def n(self) -> int:
        return sum(b.n for b in self.blocks)

    @property
    def point(self) -> OperatingPoint:
        """The operating point of the blocks (the fields their meta lacks: NaN, on, settled)."""
        return _point(self.blocks[0])

    @property
    def output_off(self) -> bool:
        return not self.point.output_on

    @property
    def settling(self) -> bool:
        """Samples that may predate a command, or the transient after the segment's start."""
        return self.transient or self.point.settling

    @property
    def idle(self) -> bool:
        """Output off (nothing was excited), or settling (no estimate may use it)."""
        return self.output_off or self.settling

    def split(self, n: int) -> tuple["Segment", "Segment | None"]:
        """The first ``n`` samples as a transient segment, and the rest (None if nothing is left)."""
        head: list[SampleBlock] = []
        for k, b in enumerate(self.blocks):
            if n <= 0:
                return Segment(head, True), Segment(self.blocks[k:])
            if b.n <= n:
                head.append(b)
                n -= b.n
                continue
            first = SampleBlock(b.first_index, b.fs_hz, {c: x[:n] for c, x in b.channels.items()},
                                flags=b.flags, gap_samples=b.gap_samples, meta=b.meta)
            rest = SampleBlock(b.first_index + n, b.fs_hz, {c: x[n:] for c, x in b.channels.items()},
                               flags=b.flags & ~BlockFlags.GAP, meta=b.meta)
            return Segment(head + [first], True), Segment([rest] + self.blocks[k + 1:])
        return Segment(head, True), None

    def recording(self, base: dict, path: Path) -> Recording:
        """The segment with the operating point its blocks carried (not the log's first one):
        an output-off segment says ``output_on: false`` and 0 A-pp (the generator's setting is
        kept as ``generator_current_pp_A``), a settling one ``settling: true``.  Its time runs on the
        log's sample clock; when that is too far from 0 for float64 (months of acquisition) the
        segment starts at 0 and the offset goes to ``start_time_s``, as the format asks.  With the
        log's own ``start_time_s`` (its sample 0 on the day's clock), the segment's start is added."""
        point, fs = self.point, self.blocks[0].fs_hz
        meta = with_point(base, dataclasses.replace(point, settling=self.settling))
        meta["sample_rate_Hz"] = fs
        meta["mcap_source"] = {"log": str(path), "first_index": self.first_index, "samples": self.n}
        if "table" in self.blocks[0].meta:  # which waveform the generator played (a count of changes, see sources)
            meta["mcap_source"]["table"] = point.table
        t0 = self.first_index / fs
        fits = times_fit(t0, self.n, fs)
        start = base.get("start_time_s", 0.0)
        if ("start_time_s" in base or not fits) and isinstance(start, (int, float)) and not isinstance(start, bool):
            meta["start_time_s"] = start + t0  # (one that is no number is named by the sidecar's check)
        try:
            rec = Recording.from_blocks(self.blocks, meta, t0_s=None if fits else 0.0)
        except RecordingError as err:
            raise RecordingError(f"{path}: segment at sample {self.first_index}: {err}") from err
        return rec


def segments(blocks: Iterable[SampleBlock]) -> list[Segment]:
    """Contiguous blocks with one operating point and one set of channels, as segments."""
    out: list[Segment] = []
    for b in blocks:
        if b.n == 0:
            continue
        last = out[-1].blocks[-1] if out else None
        if last is not None and b.first_index == last.end_index and _point(b) == _point(last) \
                and set(b.channels) == set(last.channels):
            out[-1].blocks.append(b)
        else:
            out.append(Segment([b]))
    return out


class McapSource:
    """A log's raw blocks as a pipeline source, as fast as possible or at ``speed`` x real time."""

    def __init__(self, path: str | Path, *, pace: str = "max", speed: float = 1.0) -> None:
        if pace not in ("max", "realtime"):
            raise RecordingError(f"replay speed must be 'realtime' or 'max', got {pace!r}")
        self.path = Path(path)
        self.pace, self.speed = pace, float(speed)
        meta = log_metadata(self.path)
        self._meta = meta.get("recording", {})
        self.config = meta.get("config", {})
        self.estimation = estimation_settings(meta, self.path)
        first = next(iter_blocks(self.path), None)
        if first is None:
            raise RecordingError(f"{self.path}: no raw blocks to replay")
        self.channels = list(first.channels)
        self.fs_hz = first.fs_hz
        self.dtype = next(iter(first.channels.values())).dtype
        self.name = f"replay of {self.path.name}"

    def metadata(self) -> dict:
        return dict(self._meta)

    def blocks(self, stop: threading.Event | None = None) -> Iterator[SampleBlock]:
        """The log's raw blocks as a live source gives them (the :class:`~hystbench.acquisition.sources.Source`
        protocol), paced as ``pace`` says, until the log ends or ``stop`` is set."""
        t0 = time.monotonic()
        i0 = None
        for b in iter_blocks(self.path):
            if stop is not None and stop.is_set():
                return
            if self.pace == "realtime":
                i0 = b.first_index if i0 is None else i0
                due = t0 + (b.end_index - i0) / self.fs_hz / self.speed
                wait = due - time.monotonic()
                if wait > 0:
                    (stop.wait(wait) if stop is not None else time.sleep(wait))
            yield b

    def close(self) -> None:
        pass
