"""Reading hystbench MCAP logs: messages, raw blocks, operating-point segments, recordings.

A log of a whole session may hold several operating points (a sweep) and gaps; a *segment* is a
run of contiguous raw blocks with one operating point (block meta :data:`OPERATING_KEYS`).  The
start of each is the bench settling after the change (or after a gap: what happened in it is not
known): the samples the live estimator skips (:mod:`..settling`; the log's own ``settle_s`` and
``settle_periods`` when it records them) form a segment of their own, marked ``settling`` and
left out like the output-off ones, so an offline estimate sees what the live one saw.
:func:`read_mcap_recording` gives the one segment of a log as a :class:`Recording` (what
``hystbench estimate LOG.mcap`` needs); :func:`read_mcap_segments` gives them all (``export``).
A log that was not finished (the writer was killed) is refused with a pointer to ``recover``.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterable, Iterator

from ...blocks import BlockFlags, SampleBlock
from ...errors import RecordingError
from ..recording import Recording
from ...analysis.settling import settle_samples, settling_time_s
from ...acquisition.sources import OPERATING_KEYS
from .schemas import RAW, decode_block

__all__ = ["LogMessage", "iter_log", "iter_blocks", "log_metadata", "read_mcap_segments",
           "read_mcap_recording", "McapSource", "Segment"]


@dataclass(frozen=True)
class LogMessage:
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


def iter_log(path: str | Path, topics: Iterable[str] | None = None) -> Iterator[LogMessage]:
    """Messages in file order (which is time order for a hystbench log)."""
    from mcap.reader import make_reader

    path = Path(path)
    with _open(path) as fh:
        try:
            reader = make_reader(fh)
            summary = reader.get_summary()
            if summary is None:
                raise ValueError("no summary section")
            for _, channel, msg in reader.iter_messages(topics=list(topics) if topics else None,
                                                        log_time_order=False):
                yield LogMessage(channel.topic, msg.log_time, msg.data)
        except RecordingError:
            raise
        except Exception as err:  # the mcap reader raises many kinds on a damaged file
            raise _damaged(path, err) from err


def log_metadata(path: str | Path) -> dict[str, dict]:
    """Metadata records by name, each the JSON object it was written from."""
    from mcap.reader import make_reader

    path = Path(path)
    out: dict[str, dict] = {}
    with _open(path) as fh:
        try:
            for rec in make_reader(fh).iter_metadata():
                text = rec.metadata.get("json")
                out[rec.name] = json.loads(text) if text is not None else dict(rec.metadata)
        except Exception as err:  # the mcap reader raises many kinds on a damaged file
            raise _damaged(path, err) from err
    return out


def iter_blocks(path: str | Path) -> Iterator[SampleBlock]:
    """The raw sample blocks, in order."""
    path = Path(path)
    for k, m in enumerate(iter_log(path, [RAW])):
        yield decode_block(m.data, f"{path}: raw message {k}")


def _point(block: SampleBlock) -> tuple:
    return tuple(block.meta.get(k) for k in OPERATING_KEYS)


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
    def output_off(self) -> bool:
        return self.blocks[0].meta.get("output_on", 1.0) == 0.0

    @property
    def settling(self) -> bool:
        """Samples that may predate a command, or the transient after the segment's start."""
        return self.transient or bool(self.blocks[0].meta.get("settling"))

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
        kept as ``generator_current_pp_A``), a settling one ``settling: true``."""
        meta = dict(base)
        m = self.blocks[0].meta
        for key, meta_key in (("frequency_hz", "frequency_Hz"), ("current_pp_a", "current_pp_A"),
                              ("offset_a", "offset_A")):
            if key in m:
                meta[meta_key] = float(m[key])
        if self.output_off:
            meta["generator_current_pp_A"] = meta.get("current_pp_A", 0.0)
            meta["current_pp_A"] = 0.0
            meta["output_on"] = False
        if self.settling:
            meta["settling"] = True
        meta["sample_rate_Hz"] = self.blocks[0].fs_hz
        meta["mcap_source"] = {"log": str(path), "first_index": self.first_index, "samples": self.n}
        if "table" in m:  # which waveform the generator played (a count of changes, see sources)
            meta["mcap_source"]["table"] = int(m["table"])
        try:
            rec = Recording.from_blocks(self.blocks, meta)
        except RecordingError as err:
            raise RecordingError(f"{path}: segment at sample {self.first_index}: {err}") from err
        return rec


def _segments(blocks: Iterable[SampleBlock]) -> list[Segment]:
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


def _settle(meta: dict[str, dict], base: dict):
    """(settle_s, settle_periods) of the log: what its live estimator skipped after a change."""
    est = (meta.get("config") or {}).get("estimation") or {}
    try:
        settle_s = float(est["settle_s"]) if "settle_s" in est else settling_time_s(base)
        periods = float(est.get("settle_periods", 2.0))
    except (TypeError, ValueError):
        settle_s, periods = settling_time_s(base), 2.0
    return settle_s, periods


def _split_settling(segs: list[Segment], base: dict, settle_s: float, settle_periods: float) -> list[Segment]:
    """Each excited segment's first samples (the settling after its start) as a segment of their own."""
    out: list[Segment] = []
    for s in segs:
        if s.idle:
            out.append(s)
            continue
        m = s.blocks[0].meta
        f = float(m.get("frequency_hz") or base.get("frequency_Hz") or 0.0)
        fs = s.blocks[0].fs_hz
        n = settle_samples(settle_s, settle_periods, fs, f)
        if n <= 0:
            out.append(s)
            continue
        head, rest = s.split(n)
        out.append(head)
        if rest is not None:
            out.append(rest)
    return out


def read_mcap_segments(path: str | Path, *, include_idle: bool = False) -> list[Recording]:
    """Every segment of the log as a Recording (metadata: the log's ``recording`` record with the
    segment's operating point); output-off and settling segments only with ``include_idle``."""
    path = Path(path)
    meta = log_metadata(path)
    base = meta.get("recording")
    if base is None:
        raise RecordingError(f"{path}: no 'recording' metadata record (rig, frequency_Hz, ...); "
                             "not a hystbench log?")
    segs = _split_settling(_segments(iter_blocks(path)), base, *_settle(meta, base))
    segs = [s for s in segs if include_idle or not s.idle]
    if not segs:
        raise RecordingError(f"{path}: no raw samples{'' if include_idle else ' with the output on and settled'}")
    recs = []
    for s in segs:
        rec = s.recording(base, path)
        rec.path = path
        recs.append(rec)
    return recs


def read_mcap_recording(path: str | Path, segment: int | None = None) -> Recording:
    """The log's samples as one Recording: its only segment, or segment number ``segment``."""
    path = Path(path)
    recs = read_mcap_segments(path)
    if segment is None:
        if len(recs) > 1:
            points = ", ".join(f"{r.frequency_hz:g} Hz/{r.current_pp_a:g} A-pp" + (
                f" table {r.metadata['mcap_source']['table']}" if "table" in r.metadata["mcap_source"] else "")
                for r in recs[:6])
            raise RecordingError(f"{path}: {len(recs)} segments (operating points or gaps: {points}"
                                 f"{', ...' if len(recs) > 6 else ''}); choose one, or "
                                 f"`hystbench export {path} --out DIR` writes each")
        return recs[0]
    if not 0 <= segment < len(recs):
        raise RecordingError(f"{path}: segment {segment} does not exist (0..{len(recs) - 1})")
    return recs[segment]


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
        first = next(iter_blocks(self.path), None)
        if first is None:
            raise RecordingError(f"{self.path}: no raw blocks to replay")
        self.channels = list(first.channels)
        self.fs_hz = first.fs_hz
        self.dtype = next(iter(first.channels.values())).dtype
        self.name = f"replay of {self.path.name}"

    def metadata(self) -> dict:
        return dict(self._meta)

    def blocks(self, stop=None) -> Iterator[SampleBlock]:
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
