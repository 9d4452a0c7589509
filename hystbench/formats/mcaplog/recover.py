"""Salvage an MCAP log whose writer died (``kill -9``, power cut): every complete chunk survives.

The file is walked record by record from the start; schemas, channels and metadata are kept as
they come, each chunk is decompressed and its CRC checked, and the walk stops at the first record
that is cut short or damaged.  What was read is written as a new, finished log (summary and
indexes included), so every reader opens it.  Nothing is guessed: a message is kept only if the
chunk holding it is whole.
"""

from __future__ import annotations

import io
import struct
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

from ...errors import RecordingError

__all__ = ["RecoverReport", "recover"]

_MAGIC = b"\x89MCAP0\r\n"


@dataclass
class RecoverReport:
    """What :func:`recover` salvaged and what it could not, so the user knows what the new log lacks."""

    source: Path
    out: Path
    complete: bool  # the source had its footer: nothing was missing
    chunks: int = 0
    messages: int = 0
    by_topic: Counter = field(default_factory=Counter)
    bytes_total: int = 0
    bytes_salvaged: int = 0  # source bytes up to the end of the last good record
    stopped: str = ""  # why the walk stopped before the end, if it did
    last_log_time_ns: int = 0

    def as_dict(self) -> dict:
        return {"source": str(self.source), "out": str(self.out), "complete": self.complete,
                "chunks": self.chunks, "messages": self.messages, "by_topic": dict(self.by_topic),
                "bytes_total": self.bytes_total, "bytes_salvaged": self.bytes_salvaged,
                "bytes_lost": self.bytes_total - self.bytes_salvaged, "stopped": self.stopped,
                "last_log_time_ns": self.last_log_time_ns}


def _records(fh, report: RecoverReport):
    """(opcode, body) of every whole record after the magic; sets ``report.stopped`` at a cut."""
    while True:
        head = fh.read(9)
        if not head:
            report.stopped = report.stopped or "end of file without a footer"
            return
        if len(head) < 9:
            report.stopped = "file ends inside a record header"
            return
        opcode, length = struct.unpack("<BQ", head)
        if length > report.bytes_total:
            report.stopped = f"record of {length} bytes at offset {fh.tell() - 9} is longer than the file"
            return
        body = fh.read(length)
        if len(body) < length:
            report.stopped = f"record at offset {fh.tell() - len(body) - 9} is cut short ({len(body)} of {length} bytes)"
            return
        yield opcode, body, fh.tell()


def recover(path: str | Path, out: str | Path | None = None, *, overwrite: bool = False) -> RecoverReport:
    """Write what is whole in ``path`` to ``out`` (default ``STEM-recovered.mcap``)."""
    from mcap.data_stream import ReadDataStream
    from mcap.opcode import Opcode
    from mcap.records import Channel, Chunk, Header, Message, Metadata, Schema
    from mcap.stream_reader import breakup_chunk
    from mcap.writer import CompressionType, Writer

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
    report = RecoverReport(path, out, complete=False, bytes_total=path.stat().st_size)
    schemas: dict[int, Schema] = {}
    channels: dict[int, Channel] = {}
    metadata: list[Metadata] = []
    messages: list[Message] = []
    header = None
    with fh:
        if fh.read(8) != _MAGIC:
            raise RecordingError(f"{path}: not an MCAP file (bad magic)")
        report.bytes_salvaged = 8
        for opcode, body, end in _records(fh, report):
            stream = ReadDataStream(io.BytesIO(body))
            try:
                if opcode == Opcode.HEADER:
                    header = Header.read(stream)
                elif opcode == Opcode.SCHEMA:
                    s = Schema.read(stream)
                    schemas[s.id] = s
                elif opcode == Opcode.CHANNEL:
                    c = Channel.read(stream)
                    channels[c.id] = c
                elif opcode == Opcode.METADATA:
                    metadata.append(Metadata.read(stream))
                elif opcode == Opcode.MESSAGE:
                    messages.append(Message.read(stream, len(body)))
                elif opcode == Opcode.CHUNK:
                    inner = breakup_chunk(Chunk.read(stream), validate_crc=True)
                    for rec in inner:
                        if isinstance(rec, Schema):
                            schemas[rec.id] = rec
                        elif isinstance(rec, Channel):
                            channels[rec.id] = rec
                        elif isinstance(rec, Message):
                            messages.append(rec)
                    report.chunks += 1
                elif opcode in (Opcode.DATA_END, Opcode.FOOTER):
                    report.complete = True  # the data section is whole (the summary is rebuilt anyway)
                    report.bytes_salvaged = report.bytes_total
                    break
            except Exception as err:  # a damaged record: keep what came before it
                report.stopped = (f"damaged record (opcode 0x{opcode:02x}) ending at offset {end}: "
                                  f"{type(err).__name__}: {err}")
                break
            report.bytes_salvaged = end
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        with open(out, "wb") as dst:
            w = Writer(dst, compression=CompressionType.ZSTD)
            w.start(profile=header.profile if header else "", library=header.library if header else "")
            ids = {}
            for sid, s in sorted(schemas.items()):
                ids[sid] = w.register_schema(name=s.name, encoding=s.encoding, data=s.data)
            cids = {}
            for cid, c in sorted(channels.items()):
                cids[cid] = w.register_channel(topic=c.topic, message_encoding=c.message_encoding,
                                               schema_id=ids.get(c.schema_id, 0), metadata=dict(c.metadata))
            for m in metadata:
                w.add_metadata(m.name, dict(m.metadata))
            for msg in messages:
                if msg.channel_id not in cids:
                    continue
                w.add_message(cids[msg.channel_id], log_time=msg.log_time, data=msg.data,
                              publish_time=msg.publish_time, sequence=msg.sequence)
                report.messages += 1
                report.by_topic[channels[msg.channel_id].topic] += 1
                report.last_log_time_ns = max(report.last_log_time_ns, msg.log_time)
            w.finish()
    except OSError as err:
        raise RecordingError(f"{out}: cannot write the recovered log: {err.strerror}") from err
    return report
