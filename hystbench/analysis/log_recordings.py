"""A log as interchange-format recordings, the way its live estimator saw it.

Each segment of a log (contiguous blocks at one operating point, :func:`~..formats.mcaplog.segments`)
starts with the bench settling after the change (or after a gap: what happened in it is not
known): the samples the live estimator skips (:mod:`.settling`; the log's own ``settle_s`` and
``settle_periods`` when it records them) form a segment of their own, marked ``settling`` and left
out like the output-off ones, so an offline estimate sees what the live one saw.
:func:`read_mcap_recording` gives the one segment of a log as a :class:`Recording` (what
``hystbench estimate LOG.mcap`` needs); :func:`read_mcap_segments` gives them all (``export``).
Here, not in :mod:`hystbench.formats`: how long a bench rings comes from the rig's instrument model.
"""

from __future__ import annotations

from pathlib import Path

from ..errors import RecordingError
from ..formats.mcaplog.reader import Segment, estimation_settings, iter_blocks, log_metadata, segments
from ..formats.recording import Recording, sidecar_point
from .settling import settle_samples, settling_time_s

__all__ = ["read_mcap_segments", "read_mcap_recording"]


def _settle(meta: dict[str, dict], base: dict, path: Path) -> tuple[float, float]:
    """(settle_s, settle_periods) of the log: what its live estimator skipped after a change."""
    est = estimation_settings(meta, path)
    return est.get("settle_s", settling_time_s(base)), est.get("settle_periods", 2.0)


def _split_settling(segs: list[Segment], base: dict, settle_s: float, settle_periods: float) -> list[Segment]:
    """Each excited segment's first samples (the settling after its start) as a segment of their own."""
    out: list[Segment] = []
    for s in segs:
        if s.idle:
            out.append(s)
            continue
        point = s.blocks[0].point
        f = (sidecar_point(base) if point is None else point).frequency_hz
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
    segment's operating point; its ``start_time_s``, when of the log's sample 0, becomes the
    segment's start, ``start_time_s + t0_s``); output-off and settling segments only with ``include_idle``."""
    path = Path(path)
    meta = log_metadata(path)
    base = meta.get("recording")
    if base is None:
        raise RecordingError(f"{path}: no 'recording' metadata record (rig, frequency_Hz, ...); "
                             "not a hystbench log?")
    blocks = iter_blocks(path)
    if not include_idle:  # dropped as they are read: an idle day's blocks held 1 GB for a 290 kB log
        blocks = (b for b in blocks if b.point is None or (b.point.output_on and not b.point.settling))
    segs = _split_settling(segments(blocks), base, *_settle(meta, base, path))
    segs = [s for s in segs if include_idle or not s.idle]
    if not segs:
        raise RecordingError(f"{path}: no raw samples{'' if include_idle else ' with the output on and settled'}")
    recs = []
    for s in segs:
        rec = s.recording(base, path)  # each segment's start_time_s: the log's (its sample 0) plus its own
        rec.path = path
        recs.append(rec)
    return recs


_LISTED = 12  # segments named in the refusal to pick one


def read_mcap_recording(path: str | Path, segment: int | None = None) -> Recording:
    """The log's samples as one Recording: its only segment, or segment number ``segment``."""
    path = Path(path)
    recs = read_mcap_segments(path)
    if segment is None:
        if len(recs) > 1:  # each with the number that picks it
            points = ", ".join(f"{k}: {r.frequency_hz:g} Hz/{r.current_pp_a:g} A-pp" + (
                f" table {r.metadata['mcap_source']['table']}" if "table" in r.metadata["mcap_source"] else "")
                for k, r in enumerate(recs[:_LISTED]))
            more = f", ... {len(recs) - _LISTED} more" if len(recs) > _LISTED else ""
            raise RecordingError(f"{path}: {len(recs)} segments (operating points or gaps; {points}{more}); "
                                 "choose one with --segment N (segment=N from Python), or "
                                 f"`hystbench export {path} --out DIR` writes each")
        return recs[0]
    if not 0 <= segment < len(recs):
        raise RecordingError(f"{path}: segment {segment} does not exist (0..{len(recs) - 1})")
    return recs[segment]
