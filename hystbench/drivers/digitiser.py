"""A digitiser or oscilloscope (SCPI over VISA) or an NI-DAQmx card as the bench's sample source.

On a real bench the instruments' analogue outputs (current monitor, charge amplifier, integrator,
generator) are sampled by one digitiser on the common clock, not streamed by each instrument.
:func:`open_digitiser_stream` gives the same :class:`~.stream.SampleStream` as the framed
streams: a :class:`FrameSource` that reads segments from the digitiser, so gap accounting
(from first-sample indices), stall detection, reconnection and scaling are the stream's own.

Backends, imported only when configured (python-can's interface table is the model):

    visa     SCPI over VISA (pyvisa with the pure-Python pyvisa-py: TCPIP SOCKET, USBTMC, serial)
    daqmx    NI-DAQmx (the optional ``nidaqmx`` package, ``pip install hystbench[nidaqmx]``)

Segments are read channel by channel, each from where its last read stopped; a frame holds the
span every channel has (the rest waits for the next read), so channels are never shifted against
each other, and memory the instrument lost shows as a jump in the first index: an exact gap.
"""

from __future__ import annotations

import dataclasses
import importlib
import socket
import threading
import time
from typing import TYPE_CHECKING, Any, Callable, Mapping

import numpy as np

from ..blocks import BlockFlags
from ..errors import ConfigError, ConnectionLost, InstrumentError, InstrumentTimeout, ProtocolError
from .base import Backoff, log
from .protocols import scpi
from .protocols import scpi_digitiser as sd
from .protocols.framing import DeframerStats, Frame
from .stream import FrameSource, SampleStream

if TYPE_CHECKING:
    from .protocols.bench_config import BenchConfig, DigitiserConfig

__all__ = ["ScpiDigitiser", "DigitiserFrameSource", "open_digitiser_stream", "DIGITISER_BACKENDS", "SIGNALS"]

#: The signals the digitiser must sample: the bench's four channels.
SIGNALS = ("current_A", "force_N", "flux_Wb", "command_V")

#: backend -> (module, class of its FrameSource), imported only when configured.
DIGITISER_BACKENDS: dict[str, tuple[str, str]] = {
    "visa": ("hystbench.drivers.digitiser", "DigitiserFrameSource"),
    "daqmx": ("hystbench.drivers.daqmx", "DaqmxFrameSource"),
}
_MAX_ERRORS = 32


class VisaLink:
    """A pyvisa message-based resource: text queries and exact byte reads, pyvisa's errors turned
    into TimeoutError / ConnectionError (the instrument's driver names instrument and command)."""

    def __init__(self, resource: str, timeout_s: float, backend: str = "@py") -> None:
        self.resource, self.timeout_s, self.backend = resource, timeout_s, backend
        self._inst: Any = None

    def open(self) -> None:
        try:
            import pyvisa
        except ImportError as err:  # a dependency of the package: only a broken install lands here
            raise ConfigError("the VISA digitiser needs pyvisa and pyvisa-py: pip install pyvisa pyvisa-py") from err
        self.close()
        ms = max(1, int(self.timeout_s * 1000))
        try:
            rm = pyvisa.ResourceManager(self.backend)
            inst = rm.open_resource(self.resource, open_timeout=ms)
        except (pyvisa.errors.VisaIOError, OSError, ValueError) as err:
            raise ConnectionError(f"cannot open {self.resource}: {err}") from err
        inst.read_termination = "\n"
        inst.write_termination = "\n"
        inst.timeout = ms
        inst.chunk_size = 1 << 20
        self._inst = inst

    def close(self) -> None:
        inst, self._inst = self._inst, None
        if inst is not None:
            try:
                inst.close()
            except Exception:  # closing must not raise over the real error
                pass

    def _call(self, fn: Callable[[], Any]) -> Any:
        import pyvisa

        if self._inst is None:
            raise ConnectionError(f"{self.resource} is not open")
        try:
            return fn()
        except pyvisa.errors.VisaIOError as err:
            if err.error_code != pyvisa.constants.StatusCode.error_timeout:
                raise ConnectionError(str(err)) from err
            if self._peer_closed():  # pyvisa-py 0.8 reads an instrument's close as silence until the timeout
                raise ConnectionError(f"the instrument closed the connection (seen after the {self.timeout_s:g} s "
                                      "timeout)") from err
            raise TimeoutError(str(err)) from err

    def _peer_closed(self) -> bool:
        """Whether a TCPIP SOCKET session's peer has closed (a zero-byte peek); False for any other
        interface, or when pyvisa-py's session cannot be reached (then a timeout stays a timeout)."""
        try:
            sock = self._inst.visalib.sessions[self._inst.session].interface
        except (AttributeError, KeyError, TypeError):
            return False
        if not isinstance(sock, socket.socket):
            return False
        try:
            return sock.recv(1, socket.MSG_PEEK | socket.MSG_DONTWAIT) == b""
        except BlockingIOError:
            return False
        except OSError:  # reset by the peer: closed too
            return True

    def write(self, message: str) -> None:
        self._call(lambda: self._inst.write(message))

    def query(self, message: str, timeout_s: float | None = None) -> str:
        """A reply line; ``timeout_s``: a longer deadline for this query alone (e.g. ``*OPC?``)."""
        if timeout_s is None:
            return self._call(lambda: self._inst.query(message))

        def slow() -> str:
            self._inst.timeout = max(1, int(timeout_s * 1000))
            try:
                return self._inst.query(message)
            finally:
                self._inst.timeout = max(1, int(self.timeout_s * 1000))
        return self._call(slow)

    def read_exact(self, n: int) -> bytes:
        return bytes(self._call(lambda: self._inst.read_bytes(n)))


class ScpiDigitiser:
    """The digitiser's control and waveform reads, every message from its dialect's table.

    ``open`` identifies it, sets it up (each setting followed by the dialect's error query; an error is a
    ProtocolError naming the command and every queued error), checks its sample rate against the
    bench's and starts it; ``fetch(channel)`` reads the next segment of one channel."""

    def __init__(self, link: VisaLink, dialect: sd.Dialect, fs_hz: float, *, name: str = "digitiser",
                 max_points: int = 100_000) -> None:
        self.link, self.dialect, self.fs_hz, self.name, self.max_points = link, dialect, fs_hz, name, max_points
        self.identity = ""

    def _where(self, message: str) -> str:
        return f"{self.name} ({self.link.resource}): {message!r}"

    def _io(self, message: str, fn: Callable[[], Any]) -> Any:
        try:
            return fn()
        except InstrumentError:
            raise
        except TimeoutError as err:
            raise InstrumentTimeout(f"{self._where(message)}: no answer within {self.link.timeout_s:g} s") from err
        except ConnectionError as err:
            raise ConnectionLost(f"{self._where(message)}: connection lost: {err}") from err

    def query(self, op: str, channel: str = "") -> str:
        msg = self.dialect.command(op).message(channel)
        return self._io(msg, lambda: self.link.query(msg))

    def send(self, op: str, channel: str = "", value: object = None, *, check: bool = True) -> None:
        cmd = self.dialect.command(op)
        if cmd is None:
            return
        self.send_text(cmd.message(channel, value), check=check)

    def send_text(self, msg: str, *, check: bool = True) -> None:
        self._io(msg, lambda: self.link.write(msg))
        if check:
            self.check_errors(msg)

    def check_errors(self, after: str) -> None:
        """Read the error queue the dialect's way; raise naming ``after`` and every error if it
        holds any.  SCPI: ``SYST:ERR?`` until 0.  Tektronix: ``*ESR?`` (which moves the events to
        the queue); if it has an error bit, ``ALLEv?`` gives every event at once."""
        errors = self._events() if self.dialect.reads_events else self._scpi_errors()
        if errors:
            raise ProtocolError(f"{self._where(after)}: the digitiser reports {'; '.join(errors)}")

    def _scpi_errors(self) -> list[str]:
        errors = []
        for _ in range(_MAX_ERRORS):
            try:
                code, text = scpi.parse_error_reply(self.query("error"))
            except ValueError as err:
                raise ProtocolError(f"{self._where(self.dialect.cmd('error').message())}: {err}") from err
            if code == 0:
                break
            errors.append(f"{code},\"{text}\"")
        return errors

    def _events(self) -> list[str]:
        esr_msg, ev_msg = self.dialect.cmd("event_status").message(), self.dialect.cmd("error").message()
        text = self.query("event_status")
        try:
            esr = int(text.strip().split(" ")[-1])  # '32' (headers off) or ':*ESR 32'
        except ValueError as err:
            raise ProtocolError(f"{self._where(esr_msg)}: {text.strip()!r} is not a register value") from err
        bits = [what for bit, what in sd.ESR_ERROR_BITS.items() if esr & bit]
        if not bits:
            return []
        try:
            events = sd.parse_event_reply(self.query("error"))
        except ValueError as err:
            raise ProtocolError(f"{self._where(ev_msg)}: {err}") from err
        errors = [f"{code},\"{text}\"" for code, text in events if sd.is_error_event(code)]
        return errors or [f"*ESR? = {esr} ({', '.join(bits)}) with no error in {ev_msg}"]

    def open(self, channels: tuple[str, ...] = (), segments: int = 0) -> None:
        """Identify, set up and start the digitiser; each of ``channels`` is selected once here
        with its error check (a channel the instrument lacks is refused now, not read wrongly).
        ``segments`` > 0: segmented memory of that many segments a batch, armed by :meth:`arm`."""
        self._io("open", self.link.open)
        self.identity = self.query("identity").strip()
        if len(self.identity.split(",")) != len(scpi.IDN_FIELDS):
            raise ProtocolError(f"{self._where('*IDN?')}: answer {self.identity!r} is not maker,model,serial,firmware")
        self.send("clear_status", check=False)
        for msg in self.dialect.on_open:
            self.send_text(msg)
        for op in ("clock_source", "trigger_source", "format", "unsigned", "byte_order", "points_mode"):
            self.send(op)
        self.send("points", value=self.max_points)
        for ch in channels:
            self.send("source", ch)
        text = self.query("sample_rate")
        try:
            rate = float(text)
        except ValueError as err:
            raise ProtocolError(f"{self._where(self.dialect.command('sample_rate').message())}: "
                                f"{text!r} is not a number") from err
        if abs(rate - self.fs_hz) > 1e-9 * self.fs_hz:
            raise ConfigError(f"{self.name}: samples at {rate:g} Hz but [bench] fs_hz = {self.fs_hz:g}: they must "
                              "be the same clock")
        if segments:
            self.send("acquire_mode")
            self.send("segment_count", value=segments)
        else:
            self.send("run")

    def close(self) -> None:
        try:
            if self.link._inst is not None:
                self.send("stop", check=False)
        except InstrumentError as err:
            log.info("%s: stop on close: %s", self.name, err)
        self.link.close()

    def arm_and_wait(self, wait_s: float) -> None:
        """Arm one batch of segments and wait (at most ``wait_s``) until the digitiser says it is
        complete; then its error queue is read."""
        arm = self.dialect.cmd("arm").message()
        self.send_text(arm, check=False)
        wait = self.dialect.cmd("wait").message()
        text = self._io(wait, lambda: self.link.query(wait, timeout_s=wait_s)).strip()
        if text != "1":
            raise ProtocolError(f"{self._where(wait)}: answered {text!r}, not 1")
        self.check_errors(arm)

    def time_tag(self, segment: int) -> float:
        """Seconds from the batch's first trigger to segment ``segment``'s (1-based); selects it."""
        msg = sd.compound(self.dialect.cmd("segment_index").message(value=segment),
                          self.dialect.cmd("time_tag").message())
        text = self._io(msg, lambda: self.link.query(msg))
        try:
            return float(text)
        except ValueError:
            raise ProtocolError(f"{self._where(msg)}: {text.strip()!r} is not a time") from None

    def fetch(self, channel: str) -> tuple[int, np.ndarray, bool]:
        """The next segment of ``channel``: (first index on the common clock, volts, clipped)."""
        pre, volts, clipped = self.waveform(channel)
        try:
            return pre.first_index(self.fs_hz), volts, clipped
        except ValueError as err:
            raise ProtocolError(f"{self._where(self._pre_msg(channel))} ({channel}): {err}") from err

    def _pre_msg(self, channel: str) -> str:
        return sd.compound(self.dialect.cmd("source").message(channel), self.dialect.cmd("preamble").message())

    def waveform(self, channel: str) -> tuple[sd.Preamble, np.ndarray, bool]:
        """The next segment of ``channel`` (its preamble checked: one clock period between points)."""
        # source and preamble as one program message (IEEE 488.2 ';'-separated units): as two, the
        # query would wait for the instrument's delayed ACK of the command (Nagle: 40 ms on Linux)
        pre_msg = self._pre_msg(channel)
        text = self._io(pre_msg, lambda: self.link.query(pre_msg))
        try:
            pre = sd.Preamble.parse(text, self.dialect)
            pre.start_s(self.fs_hz)
        except ValueError as err:
            raise ProtocolError(f"{self._where(pre_msg)} ({channel}): {err}") from err
        data_msg = self.dialect.command("data").message()
        self._io(data_msg, lambda: self.link.write(data_msg))
        raw = self._io(data_msg, lambda: sd.read_block(self.link.read_exact, self._where(data_msg) + f" ({channel})"))
        if len(raw) != 2 * pre.points:
            raise ProtocolError(f"{self._where(data_msg)} ({channel}): the block holds {len(raw)} bytes, the preamble "
                                f"announced {pre.points} points of 2 bytes")
        codes = np.frombuffer(raw, dtype=sd.CODE_DTYPE)
        return pre, sd.codes_to_volts(codes, pre), sd.clipped(codes)


class SegmentJoiner:
    """Per-channel segments in, frames holding every channel at the same indices out.

    Each channel's samples wait here until every channel has them; a channel whose next segment
    starts later than its last one ended (lost memory) drops what the others hold before that
    index, so the frame after it starts later: the stream reports the exact gap.  A clipped
    segment flags CLIP on every frame holding any of its span (its part past what the other
    channels have goes out in a later frame)."""

    def __init__(self, n_channels: int) -> None:
        self._first: list[int | None] = [None] * n_channels
        self._data: list[np.ndarray] = [np.empty(0)] * n_channels
        self._clips: list[tuple[int, int]] = []  # [first, end) of the segments that clipped
        self.seq = 0

    def push(self, k: int, first: int, volts: np.ndarray, clipped: bool) -> None:
        end = None if self._first[k] is None else self._first[k] + self._data[k].size
        if end is not None and first < end:  # overlap with what is held: keep only what is new
            volts, first = volts[end - first:], end
        if end is None or first > end:  # a fresh start or lost memory: what was held before is unusable
            self._first[k], self._data[k] = first, volts
        else:
            self._data[k] = np.concatenate([self._data[k], volts])
        if clipped and volts.size:
            self._clips.append((first, first + volts.size))

    def pop(self) -> Frame | None:
        if any(f is None for f in self._first):
            return None
        start = max(self._first)
        end = min(f + d.size for f, d in zip(self._first, self._data))
        if end <= start:
            return None
        rows = [d[start - f:end - f] for f, d in zip(self._first, self._data)]
        for k, (f, d) in enumerate(zip(self._first, self._data)):
            self._first[k], self._data[k] = end, d[end - f:]
        flags = int(BlockFlags.CLIP) if any(a < end and b > start for a, b in self._clips) else 0
        self._clips = [(a, b) for a, b in self._clips if b > end]
        frame = Frame(0, self.seq, start, np.vstack(rows), flags)
        self.seq = (self.seq + 1) % (1 << 32)
        return frame


class DigitiserFrameSource(FrameSource):
    """A SCPI digitiser's channels as frames (``channels``: the instrument's channel for each
    signal, in the stream's order).  An idle digitiser is asked again after ``poll_s``."""

    def __init__(self, digitiser: ScpiDigitiser, channels: list[str], *, poll_s: float = 0.02,
                 min_points: int | None = None, segments: int = 0, clock: Callable[[], float] = time.monotonic
                 ) -> None:
        self.digitiser, self.instrument_channels = digitiser, list(channels)
        self.name = digitiser.name
        # a read that brought fewer than poll_s of samples per channel waits poll_s before the next:
        # each read costs a few round trips per channel, and the digitiser's memory holds seconds
        self.poll_s = poll_s
        self.min_points = int(poll_s * digitiser.fs_hz) if min_points is None else min_points
        self.deframer_stats = DeframerStats()
        self._joiner = SegmentJoiner(len(channels))
        self._idle = threading.Event()  # never set: waits between polls are bounded by poll_s
        self._opened = False  # a refusal at the first open is the user's to fix; on a reopen, a failed attempt
        # segmented (segments > 0): batches armed one at a time; the host clock places each batch
        self.segments, self._clock = segments, clock
        self._batch_end: int | None = None  # the index after the last batch's last sample
        self._batch_done_s = 0.0  # the host clock when that batch was complete

    @classmethod
    def from_config(cls, dc: DigitiserConfig, bench: BenchConfig) -> "DigitiserFrameSource":
        d = sd.dialect(dc.dialect)
        link = VisaLink(dc.url, dc.timeout_s or bench.timeout_s)
        return cls(ScpiDigitiser(link, d, bench.fs_hz, max_points=dc.max_points),
                   [d.channel(dc.channels[s]) for s in SIGNALS],  # the file's spelling checked at load
                   segments=dc.segments if dc.acquisition == "segmented" else 0)

    def open(self) -> None:
        # what the joiner holds stays: its indices count the digitiser's clock, which a new session keeps
        try:
            self.digitiser.open(tuple(self.instrument_channels), self.segments)
        except (InstrumentTimeout, ConnectionLost, ProtocolError) as err:
            self.digitiser.link.close()
            raise ConnectionError(str(err)) from err
        except ConfigError as err:  # e.g. its rate no longer the bench's: the stream's reopen catches OSError only
            self.digitiser.link.close()
            if not self._opened:
                raise
            raise ConnectionError(str(err)) from err
        self._opened = True

    def close(self) -> None:
        self.digitiser.close()

    def read_frames(self, timeout_s: float) -> list[Frame]:
        """One segment of every channel (a protocol error drops the session: the stream reopens it
        and the lost segment becomes a gap)."""
        if self.segments:
            self.drained = True  # a batch is acquired after it is armed: nothing older waits behind it
            return self._read_batch()
        got, self.drained = 0, True
        try:
            for k, ch in enumerate(self.instrument_channels):
                first, volts, clipped = self.digitiser.fetch(ch)
                got += volts.size
                self.drained &= volts.size < self.digitiser.max_points  # less than asked: all it held
                if volts.size:
                    self._joiner.push(k, first, volts, clipped)
        except ProtocolError as err:
            self.deframer_stats.corrupt += 1
            raise ConnectionError(str(err)) from err
        frame = self._joiner.pop()
        if got < self.min_points * len(self.instrument_channels):
            self._idle.wait(min(self.poll_s, timeout_s))
        if frame is None:
            return []
        self.deframer_stats.frames += 1
        return [frame]

    def _read_batch(self) -> list[Frame]:
        """One batch of segmented acquisition: armed, waited for, each segment read with its time
        tag.  Within the batch the tags place every segment exactly (whole samples, else
        ProtocolError).  Between batches the instrument says nothing: the host clock measures the
        gap (from the previous batch's completion to this one's first trigger: this batch's
        completion less its span), at least one sample, and the batch's first frame is flagged
        GAP_ESTIMATED so the stream counts that gap as an estimate."""
        dig, fs = self.digitiser, self.digitiser.fs_hz
        wait_s = dig.link.timeout_s * (self.segments + 1)  # each segment's trigger within the reply deadline
        segs: list[tuple[int, list[tuple[np.ndarray, bool]]]] = []
        try:
            dig.arm_and_wait(wait_s)
            done_s = self._clock()
            t_ref = None
            for k in range(1, self.segments + 1):
                tag = dig.time_tag(k)
                rows, first = [], None
                for ch in self.instrument_channels:
                    pre, volts, clipped = dig.waveform(ch)
                    t = tag + pre.start_s(fs)
                    t_ref = t if t_ref is None else t_ref
                    try:
                        at = sd.whole_samples(t - t_ref, fs, f"segment {k} ({ch}) starts, from the batch's first,")
                    except ValueError as err:
                        raise ProtocolError(f"{dig.name} ({dig.link.resource}): {err}") from err
                    if first is not None and at != first:
                        raise ProtocolError(f"{dig.name} ({dig.link.resource}): segment {k}: {ch} starts {at - first} "
                                            "samples from the first channel's")
                    first = at
                    rows.append((volts, clipped))
                segs.append((int(first or 0), rows))
        except ProtocolError as err:
            self.deframer_stats.corrupt += 1
            raise ConnectionError(str(err)) from err
        span = max((f + r[0][0].size for f, r in segs), default=0)
        estimated = self._batch_end is not None
        if self._batch_end is None:
            base = 0
        else:
            gap = int(round((done_s - self._batch_done_s) * fs)) - span
            base = self._batch_end + max(gap, 1)
        self._batch_end, self._batch_done_s = base + span, done_s
        frames: list[Frame] = []
        for first, rows in segs:
            for k, (volts, clipped) in enumerate(rows):
                self._joiner.push(k, base + first, volts, clipped)
            while (frame := self._joiner.pop()) is not None:
                frames.append(frame)
        if estimated and frames:
            frames[0] = dataclasses.replace(frames[0], flags=frames[0].flags | int(BlockFlags.GAP_ESTIMATED))
        self.deframer_stats.frames += len(frames)
        return frames


def _source_class(kind: str) -> type[FrameSource]:
    module, cls = DIGITISER_BACKENDS[kind]
    return getattr(importlib.import_module(module), cls)


def open_digitiser_stream(bench: BenchConfig, *, stall_timeout_s: float = 0.5, backoff: Backoff | None = None,
                          skew_s: float | None = None) -> SampleStream:
    """The bench file's ``[digitiser]`` as one started stream of the four signals (SI units:
    volts times the file's ``scales``)."""
    dc = bench.digitiser
    if dc is None:
        raise ConfigError(f"{bench.source}: no [digitiser] table")
    source = _source_class(dc.kind).from_config(dc, bench)
    scale: Mapping[str, float] = {s: float(dc.scales.get(s, 1.0)) for s in SIGNALS}
    return SampleStream("digitiser", source, list(SIGNALS), bench.fs_hz, scale=scale,
                        skew_s=dc.skew_s if skew_s is None else skew_s, stall_timeout_s=stall_timeout_s,
                        backoff=backoff or Backoff(**bench.backoff)).start()
