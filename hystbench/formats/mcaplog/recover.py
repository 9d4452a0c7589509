"""Salvage an MCAP log whose writer died (``kill -9``, power cut) or whose bytes were damaged.

MCAP records are length-prefixed, so the file is walked record by record.  A record that runs
past the end of the file, does not parse, or a chunk whose decompressed bytes fail their CRC
starts a damaged region; the walk then scans forward for the next record that proves itself
valid (:mod:`.resync`: a chunk whose header is consistent and whose CRC checks, or a schema,
channel or metadata record that parses exactly) and carries on from there.  So damage in the
middle of a log costs the chunk it hit, not everything after it.

Two passes keep the memory to one chunk: the first walks the file and keeps only the schemas,
channels, metadata and where the good chunks are; the second decodes the good chunks again and
writes their messages to a new, finished log (summary and indexes included), so every reader
opens it.  The report says which byte ranges were skipped and why, and how many chunks and
messages were lost: exactly, from the log's own statistics when its summary survived; else the
damaged chunks that were recognised (at least that many).

Nothing is guessed: a message is kept only if the chunk holding it is whole.  (A message record
outside any chunk, which hystbench never writes, is kept only before the first damaged region:
after one, it may be a record inside a damaged uncompressed chunk.)  A file that is not MCAP, or
holds no whole message, is a :class:`RecordingError`, not an empty log.
"""

from __future__ import annotations

import os
import secrets
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ...errors import RecordingError
from .chunks import MAGIC
from .reader import check_magic
from .resync import Damage, Record, Source, next_valid_record, read_record

__all__ = ["RecoverReport", "Skipped", "recover"]


@dataclass(frozen=True)
class Skipped:
    """A byte range of the source that was not salvaged, and why its first record was refused."""

    start: int
    end: int
    why: str

    @property
    def bytes(self) -> int:
        return self.end - self.start


@dataclass
class RecoverReport:
    """What :func:`recover` salvaged and what it could not, so the user knows what the new log lacks."""

    source: Path
    out: Path
    complete: bool  # the data section was whole: nothing of the log's messages was missing
    chunks: int = 0
    messages: int = 0
    by_topic: Counter = field(default_factory=Counter)
    bytes_total: int = 0
    bytes_salvaged: int = 0  # source bytes in records that were read whole (all but `skipped`)
    stopped: str = ""  # why the walk ended before the log's footer, if it did
    last_log_time_ns: int = 0
    skipped: list[Skipped] = field(default_factory=list)
    #: Chunks and messages the log held but the new one lacks: from the log's statistics record
    #: when its summary survived (``lost_counted_from``), else the damaged chunks recognised (a
    #: lower bound; the messages in them are then unknown, None).
    chunks_lost: int = 0
    messages_lost: int | None = None
    lost_counted_from: str = ""

    @property
    def bytes_skipped(self) -> int:
        return sum(s.bytes for s in self.skipped)

    def as_dict(self) -> dict:
        return {"source": str(self.source), "out": str(self.out), "complete": self.complete,
                "chunks": self.chunks, "messages": self.messages, "by_topic": dict(self.by_topic),
                "bytes_total": self.bytes_total, "bytes_salvaged": self.bytes_salvaged,
                "bytes_lost": self.bytes_total - self.bytes_salvaged, "stopped": self.stopped,
                "last_log_time_ns": self.last_log_time_ns,
                "skipped": [{"start": s.start, "end": s.end, "bytes": s.bytes, "why": s.why} for s in self.skipped],
                "bytes_skipped": self.bytes_skipped, "chunks_lost": self.chunks_lost,
                "messages_lost": self.messages_lost, "lost_counted_from": self.lost_counted_from}


@dataclass
class _Found:
    """What the first pass keeps: small things, and where the good chunks are."""

    header: Any = None
    schemas: dict = field(default_factory=dict)
    channels: dict = field(default_factory=dict)
    metadata: list = field(default_factory=list)
    keep: list[int] = field(default_factory=list)  # offsets of the chunks (and bare messages) to copy
    per_channel: Counter = field(default_factory=Counter)  # messages in ``keep``, by channel id
    statistics: Any = None
    damaged_chunks: int = 0


def _take(found: _Found, rec: Record, trusted: bool, report: RecoverReport) -> None:
    """Keep what a valid record says: definitions always, messages from whole chunks (and bare
    ones only while ``trusted``, i.e. before any damage)."""
    from mcap.opcode import Opcode
    from mcap.records import Channel, Message, Schema

    inner = rec.value if rec.opcode == Opcode.CHUNK else [rec.value]
    messages = 0
    for r in inner:
        if isinstance(r, Schema):
            found.schemas[r.id] = r
        elif isinstance(r, Channel):
            found.channels[r.id] = r
        elif isinstance(r, Message) and (rec.opcode == Opcode.CHUNK or trusted):
            found.per_channel[r.channel_id] += 1
            messages += 1
    if rec.opcode == Opcode.CHUNK:
        found.keep.append(rec.offset)
        report.chunks += 1
    elif rec.opcode == Opcode.MESSAGE and messages:
        found.keep.append(rec.offset)
    elif rec.opcode == Opcode.HEADER:
        found.header = rec.value
    elif rec.opcode == Opcode.METADATA:
        found.metadata.append(rec.value)
    elif rec.opcode == Opcode.STATISTICS:
        found.statistics = rec.value


def _walk(src: Source, report: RecoverReport) -> _Found:
    """The first pass: every valid record from the magic to the footer, resynchronising after damage."""
    from mcap.opcode import Opcode

    found, pos, data_end = _Found(), len(MAGIC), False
    while pos < src.size:
        rec = read_record(src, pos)
        if isinstance(rec, Damage):
            nxt = next_valid_record(src, pos + 1)
            found.damaged_chunks += rec.chunk + nxt.damaged_chunks
            report.skipped.append(Skipped(pos, nxt.offset, rec.why))
            if nxt.record is None:
                report.stopped = f"no valid record after offset {pos} ({rec.why})"
                break
            rec = nxt.record
        _take(found, rec, trusted=not report.skipped, report=report)
        pos = rec.end
        if rec.opcode == Opcode.DATA_END:
            data_end = True
            report.complete = not report.skipped  # the data section was whole
        if rec.opcode == Opcode.FOOTER:
            end = rec.end + len(MAGIC) if src.read(rec.end, len(MAGIC)) == MAGIC else rec.end
            if end < src.size:  # said "the log was complete" over a second log appended after it
                report.skipped.append(Skipped(end, src.size, "after the log's footer and closing magic (another log "
                                                             "appended, or junk): a recovery salvages one log"))
            break
    else:
        report.stopped = "the file ends without a footer" if not data_end else "the file ends inside its summary"
    return found


def _write(src: Source, found: _Found, tmp: Path, report: RecoverReport) -> None:
    """The second pass: the kept messages, in file order, into a new finished log at ``tmp``."""
    from mcap.opcode import Opcode
    from mcap.records import Message
    from mcap.writer import CompressionType, Writer

    header = found.header
    with open(tmp, "xb") as dst:
        w = Writer(dst, compression=CompressionType.ZSTD)
        w.start(profile=header.profile if header else "", library=header.library if header else "")
        schema_ids = {sid: w.register_schema(name=s.name, encoding=s.encoding, data=s.data)
                      for sid, s in sorted(found.schemas.items())}
        channel_ids = {cid: w.register_channel(topic=c.topic, message_encoding=c.message_encoding,
                                               schema_id=schema_ids.get(c.schema_id, 0), metadata=dict(c.metadata))
                       for cid, c in sorted(found.channels.items())}
        for m in found.metadata:
            w.add_metadata(m.name, dict(m.metadata))
        for offset in found.keep:
            rec = read_record(src, offset)
            if isinstance(rec, Damage):  # the same bytes read well a moment ago
                raise RecordingError(f"{report.source}: changed while being recovered ({rec.why})")
            for msg in rec.value if rec.opcode == Opcode.CHUNK else [rec.value]:
                if not isinstance(msg, Message) or msg.channel_id not in channel_ids:
                    continue
                w.add_message(channel_ids[msg.channel_id], log_time=msg.log_time, data=msg.data,
                              publish_time=msg.publish_time, sequence=msg.sequence)
                report.messages += 1
                report.by_topic[found.channels[msg.channel_id].topic] += 1
                report.last_log_time_ns = max(report.last_log_time_ns, msg.log_time)
        w.finish()


def _count_losses(found: _Found, report: RecoverReport) -> None:
    """What the new log lacks: exact from the log's own statistics, else a lower bound."""
    stats = found.statistics
    if stats is not None:
        report.chunks_lost = max(0, stats.chunk_count - report.chunks)
        report.messages_lost = max(0, stats.message_count - report.messages)
        report.lost_counted_from = "counted from the log's statistics record"
    else:
        report.chunks_lost = found.damaged_chunks
        report.lost_counted_from = "at least: the damaged chunks recognised; the log's statistics did not survive"


def recover(path: str | Path, out: str | Path | None = None, *, overwrite: bool = False) -> RecoverReport:
    """Write what is whole in ``path`` to ``out`` (default ``STEM-recovered.mcap``)."""
    path = Path(path)
    out = Path(out) if out is not None else path.with_name(f"{path.stem}-recovered.mcap")
    if out.resolve() == path.resolve():
        raise RecordingError(f"{out}: the recovered log must not replace its source")
    if out.exists() and not overwrite:
        raise RecordingError(f"{out}: already exists; pass --overwrite to replace it")
    try:
        fh = open(path, "rb")
    except OSError as err:
        raise RecordingError(f"{path}: cannot open: {err.strerror}") from err
    with fh:
        src = Source(fh, check_magic(fh, path))
        report = RecoverReport(path, out, complete=False, bytes_total=src.size)
        found = _walk(src, report)
        report.bytes_salvaged = src.size - report.bytes_skipped
        if not sum(found.per_channel[c] for c in found.channels):
            why = report.stopped or (report.skipped[0].why if report.skipped else "the log holds no messages")
            raise RecordingError(f"{path}: nothing to salvage: no whole chunk with a message of a known channel "
                                 f"in its {src.size} bytes ({why})")
        tmp = out.with_name(f".{out.name}.{secrets.token_hex(4)}.tmp")
        try:
            out.parent.mkdir(parents=True, exist_ok=True)
            _write(src, found, tmp, report)
            os.replace(tmp, out)
        except OSError as err:
            raise RecordingError(f"{out}: cannot write the recovered log: {err.strerror or err}") from err
        finally:
            tmp.unlink(missing_ok=True)
    _count_losses(found, report)
    return report
