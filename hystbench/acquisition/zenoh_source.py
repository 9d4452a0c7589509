"""A bench's samples as its daemon publishes them, wherever the bench is: a source for the pipeline.

A daemon publishes every raw block on ``hystbench/<bench>/raw`` (``[zenoh] publish_raw``, on by
default).  Through a router, that key reaches any PC of the lab, so ``hystbench record --source
zenoh --bench B --connect tcp/router:7447`` keeps a log of bench B on the analyst's PC while B's
daemon sweeps; ``diagnose``, ``replay`` and ``export`` read that log like any other.  The log's
metadata are the daemon's own (its health's ``recording``: rig, sample rate, ...), so the diagnosis
knows which rig it is.

What zenoh lost on the way (raw blocks are published with congestion control DROP, so that a slow
subscriber never holds up the bench) shows as a gap, counted from the blocks' own sample indices:
the block after a loss has ``BlockFlags.GAP`` and ``gap_samples``, and no estimate spans it.
"""

from __future__ import annotations

import dataclasses
import threading
import time
from typing import TYPE_CHECKING, Any, Iterator

from ..blocks import BlockFlags, SampleBlock
from ..errors import NetworkError, RecordingError
from ..formats.raw_block import decode
from .zenoh_bus import Subscription, key, open_session, query_json

if TYPE_CHECKING:
    import zenoh

__all__ = ["ZenohSource"]


class ZenohSource:
    """The raw blocks of bench ``bench`` from zenoh (module docstring), as a pipeline's source.

    Opening asks the bench's ``health`` (within ``timeout_s``) for its recording metadata and
    subscribes; :meth:`blocks` ends when ``stop`` is set or, with ``duration_s``, once that many
    seconds of the bench's samples came (by their indices, lost ones included; whole blocks), and
    raises :class:`RecordingError` naming the bench and the key when no block came for
    ``stall_timeout_s`` (the daemon stopped, or publishes no raw blocks).  ``lost_samples``: what
    zenoh lost on the way (gaps the daemon's own blocks flag are not counted there)."""

    def __init__(self, bench: str, zenoh_config: zenoh.Config, *, duration_s: float | None = None,
                 timeout_s: float = 2.0, stall_timeout_s: float = 5.0, queue_blocks: int = 2000) -> None:
        self.bench = bench
        self.duration_s = duration_s
        self.raw_key = key(bench, "raw")  # validates the name
        self.name = f"zenoh {self.raw_key}"
        self.stall_timeout_s = float(stall_timeout_s)
        self.lost_samples = 0  # lost on the way here, counted from the jumps in the blocks' indices
        self._session = open_session(zenoh_config)
        try:
            replies = [r for r in query_json(self._session, key(bench, "health"), timeout_s=timeout_s) if r.get("ok", True)]
            if not replies:
                raise NetworkError(f"bench {bench!r}: no daemon answered {key(bench, 'health')} within {timeout_s:g} s "
                                   "(is it running, and does this session reach it?)")
            recording = replies[0].get("recording")
            if not isinstance(recording, dict) or not recording.get("sample_rate_Hz"):
                raise RecordingError(f"bench {bench!r}: its health names no recording metadata (sample rate, "
                                     "rig): a daemon older than this client")
            self._meta: dict[str, Any] = dict(recording)
            self.fs_hz = float(recording["sample_rate_Hz"])
            self.channels: list[str] = [str(c) for c in replies[0].get("channels") or []]
            self._sub = Subscription(self._session, self.raw_key, maxsize=queue_blocks)
        except BaseException:
            self._session.close()
            raise

    def metadata(self) -> dict:
        return {**self._meta, "source": self.name}

    @property
    def dropped_blocks(self) -> int:
        """Blocks this side's queue dropped because the pipeline fell behind (they show as gaps)."""
        return self._sub.dropped

    def blocks(self, stop: threading.Event | None = None) -> Iterator[SampleBlock]:
        expected: int | None = None
        end: int | None = None
        heard = time.monotonic()
        while (stop is None or not stop.is_set()) and (end is None or expected < end):
            item = self._sub.get(min(0.2, self.stall_timeout_s))
            if item is None:
                if time.monotonic() - heard >= self.stall_timeout_s:
                    raise RecordingError(f"bench {self.bench!r}: no raw block on {self.raw_key} for "
                                         f"{self.stall_timeout_s:g} s (the daemon stopped, or its "
                                         "[zenoh] publish_raw is off)")
                continue
            heard = time.monotonic()
            block = decode(item[1], f"{self.raw_key}: raw block")
            if expected is not None and block.first_index < expected:
                raise RecordingError(f"bench {self.bench!r}: its sample clock went back from {expected} to "
                                     f"{block.first_index} (its daemon restarted?); the log ends here")
            if expected is not None and block.first_index > expected:
                # the whole jump is the gap before this block; what the daemon did not flag itself
                # was lost on the way here
                self.lost_samples += max(0, block.first_index - expected - block.gap_samples)
                block = dataclasses.replace(block, flags=block.flags | BlockFlags.GAP,
                                            gap_samples=block.first_index - expected)
            if end is None and self.duration_s is not None:
                end = block.first_index + int(round(self.duration_s * self.fs_hz))
            expected = block.end_index
            yield block

    def close(self) -> None:
        self._sub.close()
        self._session.close()
