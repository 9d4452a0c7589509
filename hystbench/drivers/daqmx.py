"""NI-DAQmx as the bench's sample source (``[digitiser] kind = "daqmx"``): continuous,
hardware-timed acquisition of the four signals on the generator's sample clock or trigger.

``nidaqmx`` (NI's Python API, ``pip install hystbench[nidaqmx]``) is imported only when this
backend is opened, and it needs NI's C driver (NI-DAQmx) even for simulated devices; each missing
piece is a ConfigError saying what to install.

Exact indices: the task's buffer may overwrite what was not read in time
(``OVERWRITE_UNREAD_SAMPLES``); every read asks for samples by their absolute position
(``relative_to = FIRST_SAMPLE``, ``offset`` = the next index wanted), after checking
``total_samp_per_chan_acquired`` against the buffer: samples already overwritten are skipped and
the frame starts later, which the stream reports as an exact gap.  Nothing is read twice or
filled in.  Index 0 is the task's first sample: the generator's start trigger when one is given.
Samples overwritten during a read (the reader was behind) are skipped the same way, the task
running on.  Any other read error ends the task; the stream reopens it, and a new task counts from
its own first sample, whose place on the old count nothing on the card records: it starts a new
epoch after the old one's last sample plus the time the host clock measured between the last
read and the new start (at least one sample), and its first frame is flagged GAP_ESTIMATED, so the
stream reports the gap and counts it as estimated.  (With a start trigger, the new task's first
sample comes at the next trigger, after the host's start: the estimate is then short of it.)
"""

from __future__ import annotations

import importlib
import threading
import time
from typing import TYPE_CHECKING, Any, Callable

import numpy as np

from ..blocks import BlockFlags
from ..errors import ConfigError
from .protocols.framing import DeframerStats, Frame
from .stream import FrameSource

if TYPE_CHECKING:
    from .protocols.bench_config import BenchConfig, DigitiserConfig

__all__ = ["DaqmxFrameSource", "INSTALL_HINT"]

INSTALL_HINT = "pip install hystbench[nidaqmx] (NI's nidaqmx package), and NI-DAQmx, NI's driver"
RANGE_V = 10.0
#: DAQmx's "samples no longer available": overwritten while being read (the reader was behind)
SAMPLES_NO_LONGER_AVAILABLE = -200279


def _import(where: str = "[digitiser]") -> tuple[Any, Any, Any, Any]:
    """(nidaqmx, its constants, stream_readers, errors), or a ConfigError saying what to install
    (``where``: the bench file and table that asked for it)."""
    try:
        return tuple(importlib.import_module(m) for m in ("nidaqmx", "nidaqmx.constants", "nidaqmx.stream_readers",
                                                           "nidaqmx.errors"))  # type: ignore[return-value]
    except ImportError as err:
        raise ConfigError(f'{where} kind = "daqmx" needs the nidaqmx package, which is not installed: '
                          f"{INSTALL_HINT}") from err


class DaqmxFrameSource(FrameSource):
    """The task's channels as frames, one per read (``channels``: physical channels, in the
    stream's order; ``buffer_s``: the task's buffer, in seconds of samples)."""

    def __init__(self, channels: list[str], fs_hz: float, *, clock_source: str = "", trigger_source: str = "",
                 name: str = "digitiser", buffer_s: float = 10.0, max_read: int = 100_000,
                 poll_s: float = 0.005, timeout_s: float = 1.0, where: str = "[digitiser]",
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.channels, self.fs_hz = list(channels), float(fs_hz)
        self.clock_source, self.trigger_source, self.name = clock_source, trigger_source, name
        self.where = where  # named in the errors a user can fix: the bench file and its table
        self.buffer = int(round(buffer_s * fs_hz))
        self.max_read, self.poll_s, self.timeout_s = max_read, poll_s, timeout_s
        self.deframer_stats = DeframerStats()
        self._task: Any = None
        self._reader: Any = None
        self._mods: tuple[Any, ...] = ()
        self._next = 0  # the next sample index to read, on the task's own count
        # the task's count placed on the stream's: epoch base, the end delivered so far and when
        self._clock, self._base, self._flag = clock, 0, 0
        self._end: int | None = None
        self._end_s = 0.0
        self._seq = 0
        self.skipped = 0  # samples overwritten before they were read (each a gap in the stream)
        self._idle = threading.Event()

    @classmethod
    def from_config(cls, dc: DigitiserConfig, bench: BenchConfig) -> "DaqmxFrameSource":
        from .digitiser import SIGNALS

        return cls([dc.channels[s] for s in SIGNALS], bench.fs_hz, clock_source=dc.clock_source,
                   trigger_source=dc.trigger_source, timeout_s=dc.timeout_s or bench.timeout_s,
                   where=f"{bench.source} [digitiser]")

    def open(self) -> None:
        nidaqmx, const, readers, errors = self._mods = _import(self.where)
        self.close()
        try:
            task = nidaqmx.Task()
        except errors.DaqNotFoundError as err:
            raise ConfigError(f'{self.where} kind = "daqmx": NI-DAQmx (NI\'s driver) is not installed: '
                              f"{INSTALL_HINT}") from err
        try:
            for ch in self.channels:
                task.ai_channels.add_ai_voltage_chan(ch, min_val=-RANGE_V, max_val=RANGE_V)
            task.timing.cfg_samp_clk_timing(self.fs_hz, source=self.clock_source,
                                            sample_mode=const.AcquisitionType.CONTINUOUS, samps_per_chan=self.buffer)
            if self.trigger_source:
                task.triggers.start_trigger.cfg_dig_edge_start_trig(self.trigger_source)
            task.in_stream.over_write = const.OverwriteMode.OVERWRITE_UNREAD_SAMPLES
            task.in_stream.relative_to = const.ReadRelativeTo.FIRST_SAMPLE
            self._reader = readers.AnalogMultiChannelReader(task.in_stream)
            task.start()
        except errors.DaqError as err:
            task.close()
            raise ConnectionError(f"{self.name}: NI-DAQmx refused the task: {err}") from err
        self._task, self._next = task, 0  # a new task counts from its own first sample
        if self._end is not None:  # a new epoch: after the last sample delivered, by the host clock's measure
            self._base = self._end + max(1, int(round((self._clock() - self._end_s) * self.fs_hz)))
            self._flag = int(BlockFlags.GAP_ESTIMATED)

    def close(self) -> None:
        task, self._task = self._task, None
        if task is not None:
            try:
                task.close()
            except Exception:  # closing must not raise over the real error
                pass

    def read_frames(self, timeout_s: float) -> list[Frame]:
        if self._task is None:
            raise ConnectionError(f"{self.name}: the NI-DAQmx task is not running")
        errors = self._mods[3]
        try:
            stream = self._task.in_stream
            acquired = int(stream.total_samp_per_chan_acquired)
            oldest = max(0, acquired - self.buffer)
            if self._next < oldest:  # overwritten before it was read: skip it, the stream sees the gap
                self.skipped += oldest - self._next
                self._next = oldest
            n = min(acquired - self._next, self.max_read)
            self.drained = n == acquired - self._next  # every sample acquired so far is read
            if n <= 0:
                self._idle.wait(min(self.poll_s, timeout_s))
                return []
            data = np.empty((len(self.channels), n), dtype=np.float64)
            stream.offset = self._next
            self._reader.read_many_sample(data, number_of_samples_per_channel=n, timeout=self.timeout_s)
        except errors.DaqError as err:
            self.drained = False
            if getattr(err, "error_code", None) == SAMPLES_NO_LONGER_AVAILABLE:
                # the task runs on: the next read skips to what the buffer still holds (an exact gap);
                # a new task would count from its own first sample, behind what the stream already has
                return []
            raise ConnectionError(f"{self.name}: NI-DAQmx read at sample {self._next}: {err}") from err
        frame = Frame(0, self._seq, self._base + self._next, data, self._flag)
        self._seq = (self._seq + 1) % (1 << 32)
        self._next += n
        self._flag, self._end, self._end_s = 0, self._base + self._next, self._clock()
        self.deframer_stats.frames += 1
        return [frame]
