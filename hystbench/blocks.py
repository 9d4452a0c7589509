"""The sample block: the one type that carries samples from a source to every sink.

Time inside the pipeline is an integer sample index plus the sample rate; nanoseconds are derived
only at the boundaries (MCAP, zenoh).  Channel names are the recording-format column names
(``current_A``, ``force_N``, ``flux_Wb``, ``sense_V``, ``command_V``) so that a block, a CSV
recording and an MCAP log all say the same thing the same way.

What the generator played while a block was sampled is its ``point``, a typed
:class:`~hystbench.messages.OperatingPoint`; ``meta`` is that point's wire form (a flat mapping of
numbers: what the raw-block codec writes, MCAP and zenoh alike) together with anything else a driver
notes (e.g. a channel's skew).  ``point`` is read from ``meta`` once, the first time it is asked.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass, field
from typing import Mapping

import numpy as np

from .messages import OPERATING_KEYS, OperatingPoint

#: Channels the recording format defines, with their units.
CHANNEL_UNITS: Mapping[str, str] = {
    "current_A": "A",
    "force_N": "N",
    "flux_Wb": "Wb",
    "sense_V": "V",
    "command_V": "V",
}


class BlockFlags(enum.IntFlag):
    """What is wrong with a block, carried with it, so no stage estimates across lost or clipped samples."""

    NONE = 0
    GAP = 1  #: samples before this block were lost (see ``gap_samples``)
    OVERRUN = 2  #: a reader fell behind and lost samples
    CLIP = 4  #: at least one sample reached an ADC or amplifier limit
    GAP_ESTIMATED = 8  #: the gap before this block was measured by the host clock, not counted (an estimate)


@dataclass(frozen=True)
class SampleBlock:
    """Samples ``first_index .. first_index + n - 1`` of every channel, at ``fs_hz``; ``meta``
    (numbers by name, the operating point's among them) is not changed once the block is made."""

    first_index: int
    fs_hz: float
    channels: Mapping[str, np.ndarray]
    flags: BlockFlags = BlockFlags.NONE
    gap_samples: int = 0
    meta: Mapping[str, float] = field(default_factory=dict)

    def __post_init__(self) -> None:
        shapes = {np.shape(x) for x in self.channels.values()}
        if len(shapes) > 1:
            lengths = {name: np.shape(x) for name, x in self.channels.items()}
            raise ValueError(f"channels of one block must have the same length, got {lengths}")
        if self.fs_hz <= 0:
            raise ValueError(f"fs_hz must be positive, got {self.fs_hz}")
        # counted once: the aligner and the stages ask every block's n and end_index many times over
        object.__setattr__(self, "_n", len(next(iter(self.channels.values()))) if self.channels else 0)

    @property
    def n(self) -> int:
        return self._n  # type: ignore[attr-defined]

    @property
    def point(self) -> OperatingPoint | None:
        """The operating point the block was played at, read from ``meta`` on first use and kept;
        None when ``meta`` names none (no key of ``OPERATING_KEYS``: a driver's raw block, a
        hand-made one).  Keys such a meta lacks are :meth:`OperatingPoint.from_meta`'s defaults."""
        try:
            return self._point  # type: ignore[attr-defined]
        except AttributeError:
            meta = self.meta
            point = OperatingPoint.from_meta(meta) if any(k in meta for k in OPERATING_KEYS) else None
            object.__setattr__(self, "_point", point)
            return point

    @property
    def end_index(self) -> int:
        """Index one past the last sample (the next block's ``first_index`` if none is lost)."""
        return self.first_index + self.n

    @property
    def t0_ns(self) -> int:
        return round(self.first_index * 1e9 / self.fs_hz)

    def time_s(self) -> np.ndarray:
        return (self.first_index + np.arange(self.n)) / self.fs_hz


def concatenate(blocks: list[SampleBlock]) -> SampleBlock:
    """Join consecutive blocks into one; refuses blocks that are not contiguous."""
    if not blocks:
        raise ValueError("no blocks to concatenate")
    first = blocks[0]
    for prev, nxt in zip(blocks, blocks[1:]):
        if nxt.first_index != prev.end_index:
            raise ValueError(
                f"blocks are not contiguous: {prev.end_index} then {nxt.first_index}"
            )
    names = list(first.channels)
    flags = BlockFlags.NONE
    for b in blocks:
        flags |= b.flags
    return SampleBlock(
        first_index=first.first_index,
        fs_hz=first.fs_hz,
        channels={k: np.concatenate([b.channels[k] for b in blocks]) for k in names},
        flags=flags,
        gap_samples=first.gap_samples,
        meta=dict(first.meta),
    )


__all__ = ["CHANNEL_UNITS", "BlockFlags", "SampleBlock", "concatenate"]
