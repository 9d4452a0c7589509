"""Emulated flux integrator on a python-can bus (virtual by default): the commands of
``protocols.can_integrator``, a heartbeat, and the output voltage as CAN FD stream frames
(``protocols.can_stream``: 24-bit codes, 17 to a frame).

The stream frames go on ``stream_channel`` when one is given (default: the command channel, one
bus for both): on python-can's virtual bus every handle of a channel is handed every frame and
filters in Python, so the emulated bench puts the stream on a second virtual channel, sparing the
driver's command handle the 5 900 frames a second a CAN controller or kernel filter would drop.

U = gain * flux * (rig sense turns / set turns) - U at the last reset; frozen in HOLD; clipped at
+-10 V with OVERLOAD.  The rig's flux channel already is the integrator's AC-only (and, with
``integrator_leak``, lossy) view of the sense-coil voltage.
"""

from __future__ import annotations

import functools
import queue
import threading
import time
from typing import TYPE_CHECKING

import numpy as np

from ...blocks import SampleBlock
from ...errors import ConfigError
from ...drivers.protocols import can_integrator as ci
from ...drivers.protocols import can_stream
from ...drivers.protocols.framing import warm_crc_rows
from .common import Faults, FrameEmitter, log

if TYPE_CHECKING:
    import can

__all__ = ["FluxIntegratorEmulator", "INTEGRATOR_STREAM_ID", "emulator_bus"]

INTEGRATOR_STREAM_ID = 4


@functools.cache
def _shared_message_virtual_bus() -> type:
    """python-can's VirtualBus, but ``send`` puts one Message in every other handle's queue (see
    :func:`emulator_bus`); made on first use, so importing the emulators does not import python-can."""
    import can
    from can.interfaces.virtual import VirtualBus

    class SharedMessageVirtualBus(VirtualBus):
        def send(self, msg: can.Message, timeout: float | None = None) -> None:
            self._check_if_open()
            msg.timestamp = time.time()
            msg.channel, msg.is_rx = self.channel_id, True
            all_sent = True
            for bus_queue in self.channel:
                if bus_queue is self.queue and not self.receive_own_messages:
                    continue
                try:
                    bus_queue.put(msg, block=True, timeout=timeout)
                except queue.Full:
                    all_sent = False
            if not all_sent:
                raise can.CanOperationError("Could not send message to one or more recipients")

        def send_batch(self, msgs: list[can.Message], timeout: float | None = None) -> None:
            """``send`` of each message in turn, but one lock round per receiving queue instead of
            one per message (a 5000-sample tick's 295 stream frames); an unbounded queue (python-can's default,
            the drivers') takes them all at once, as ``Queue.put`` would one by one."""
            self._check_if_open()
            now = time.time()
            for msg in msgs:
                msg.timestamp, msg.channel, msg.is_rx = now, self.channel_id, True
            all_sent = True
            for bus_queue in self.channel:
                if bus_queue is self.queue and not self.receive_own_messages:
                    continue
                if bus_queue.maxsize > 0:
                    for msg in msgs:
                        try:
                            bus_queue.put(msg, block=True, timeout=timeout)
                        except queue.Full:
                            all_sent = False
                    continue
                with bus_queue.not_empty:  # Queue.put's own steps, for the whole batch
                    bus_queue.queue.extend(msgs)
                    bus_queue.unfinished_tasks += len(msgs)
                    bus_queue.not_empty.notify(len(msgs))
            if not all_sent:
                raise can.CanOperationError("Could not send message to one or more recipients")

    return SharedMessageVirtualBus


@functools.cache
def stream_frame_type() -> type:
    """``can.Message`` for the emulator's CAN FD stream frames, made as
    ``StreamFrame(can_id, data)``: the same slots as ``can.Message(arbitration_id=can_id,
    data=data, is_extended_id=False, is_fd=True, bitrate_switch=True)``, set directly (python-can's
    keyword handling and checks cost half of the 295 frames a 5000-sample tick makes; the emulator
    gives 64 valid bytes).  A subclass: receivers see a ``can.Message``."""
    import can

    class StreamFrame(can.Message):
        __slots__ = ()

        def __init__(self, can_id: int, data: bytes) -> None:  # noqa: D107 (all of can.Message's slots)
            self.timestamp, self.arbitration_id, self.channel, self.dlc = 0.0, can_id, None, len(data)
            self.is_extended_id = self.is_remote_frame = self.is_error_frame = False
            self.error_state_indicator = False
            self.is_fd = self.bitrate_switch = self.is_rx = True
            self.data = bytearray(data)

    return StreamFrame


def emulator_bus(interface: str, channel: str) -> can.BusABC:
    """The emulator's own bus handle.  On python-can's virtual bus, a handle whose ``send`` hands
    every other handle of the channel the same Message instead of a deep copy each (python-can
    copies once per receiver: at 5 900 stream frames a second to the driver's two handles, that
    copying was the emulator's largest cost).  Safe because a sent Message is never touched again
    (the emulator builds a new one per frame) and receivers only read theirs.  Other interfaces:
    the stock bus.  The drivers always use stock python-can."""
    if interface == "virtual":
        return _shared_message_virtual_bus()(channel=channel, receive_own_messages=False, fd=True)
    import can

    try:
        return can.Bus(interface=interface, channel=channel, receive_own_messages=False, fd=True)
    except (can.CanError, ImportError, ValueError, OSError) as err:
        raise ConfigError(f"emulated flux_integrator: interface {interface!r}, channel {channel!r}: python-can cannot "
                          f"open it ({type(err).__name__}: {err}); check [flux_integrator] interface and channel") from err


class FluxIntegratorEmulator:
    """The flux integrator of the module docstring, on a real python-can bus, so its driver is tested
    with no hardware."""

    kind = "flux_integrator"

    def __init__(self, *, interface: str = "virtual", channel: str = "hystbench", node: int = 0x10,
                 true_turns: int = 10, firmware: int = 0x0105, stream_channel: str = "") -> None:
        self.faults = Faults()
        self.interface, self.channel, self.node = interface, channel, node
        self.stream_channel = stream_channel or channel
        self.true_turns = true_turns
        self.firmware = firmware
        self.state = {"gain_v_per_wb": 1e5, "turns": 1, "hold": False, "stream": False}
        self.overload = False
        self._offset_v = 0.0  # output at the last reset
        self._last_u = 0.0  # newest output, before the reset offset
        self._reset_pending = False
        self.emitter = FrameEmitter(INTEGRATOR_STREAM_ID, can_stream.SAMPLES_PER_FRAME, self.faults,
                                    encode=can_stream.encode_frames, seq_modulus=can_stream.SEQ_MODULUS)
        warm_crc_rows()  # compiled now, not on the emulator clock's first block
        self._lock = threading.RLock()
        self._bus = emulator_bus(interface, channel)
        self._stream_bus = (self._bus if self.stream_channel == channel
                            else emulator_bus(interface, self.stream_channel))
        self._tx_lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._serve, name="emu-integrator", daemon=True)
        self._thread.start()

    @property
    def addresses(self) -> dict[str, str | int]:
        return {"can_interface": self.interface, "can_channel": str(self.channel),
                "can_stream_channel": str(self.stream_channel), "node": self.node}

    def disconnect(self) -> None:
        """Bus-off: no replies, no heartbeat, no stream."""
        self.faults.silent = True

    def reconnect(self) -> None:
        self.faults.silent = False

    def _send(self, can_id: int, data: bytes, fd: bool = False) -> None:
        import can

        with self._tx_lock:
            self._bus.send(can.Message(arbitration_id=can_id, data=data, is_extended_id=False, is_fd=fd,
                                       bitrate_switch=fd), timeout=0.5)

    # --- commands ----------------------------------------------------------------------------------
    def handle(self, data: bytes) -> bytes:
        name, code, value = ci.decode_command(data)
        if name is None:
            return ci.encode_reply(code, 1)
        op = ci.OPS[name]
        with self._lock:
            if op.value != "none" and ((op.minimum is not None and value < op.minimum)
                                       or (op.maximum is not None and value > op.maximum)):
                return ci.encode_reply(code, 2)
            if name == "identify":
                return ci.encode_reply(code, 0, "u32", ci.DEVICE_TYPE << 16 | self.firmware)
            if name == "reset":
                self._reset_pending = True
            elif name == "hold":
                self.state["hold"] = bool(value)
            elif name == "stream":
                self.state["stream"] = bool(value)
            elif name in ("set_gain", "get_gain"):
                if name == "set_gain":
                    self.state["gain_v_per_wb"] = float(np.float32(value))
                return ci.encode_reply(code, 0, "f32", self.state["gain_v_per_wb"])
            elif name in ("set_turns", "get_turns"):
                if name == "set_turns":
                    self.state["turns"] = int(value)
                return ci.encode_reply(code, 0, "u32", self.state["turns"])
            elif name == "get_status":
                return ci.encode_reply(code, 0, "u32", self._status_bits())
            return ci.encode_reply(code, 0)

    def _status_bits(self) -> int:
        s = ci.STATUS["HOLD"] if self.state["hold"] else ci.STATUS["INTEGRATING"]
        s |= ci.STATUS["OVERLOAD"] if self.overload else 0
        s |= ci.STATUS["STREAMING"] if self.state["stream"] else 0
        return s

    # --- the output ----------------------------------------------------------------------------------
    def output_volts(self, flux_wb: np.ndarray) -> tuple[np.ndarray, bool]:
        with self._lock:
            if self.state["hold"]:
                u = np.full_like(flux_wb, self._last_u - self._offset_v)
            else:
                raw = flux_wb * self.state["gain_v_per_wb"] * self.true_turns / self.state["turns"]
                if self._reset_pending and raw.size:
                    self._offset_v, self._reset_pending = float(raw[0]), False
                if raw.size:
                    self._last_u = float(raw[-1])
                u = raw - self._offset_v
            clipped = bool(np.any(np.abs(u) > ci.FULL_SCALE_V))
            self.overload = clipped
            return np.clip(u, -ci.FULL_SCALE_V, ci.FULL_SCALE_V), clipped

    def on_block(self, block: SampleBlock) -> None:
        u, clipped = self.output_volts(block.channels["flux_Wb"])
        if not self.state["stream"]:
            self.emitter.skip(u.size)
            return
        msgs = list(map(functools.partial(stream_frame_type(), ci.stream_id(self.node)),
                        self.emitter.emit(block.first_index, u[None, :], 4 if clipped else 0)))
        batch = getattr(self._stream_bus, "send_batch", None)  # the emulator's virtual bus: all at once
        with self._tx_lock:
            for part in [msgs] if batch is not None else [[m] for m in msgs]:
                try:
                    if batch is not None:
                        batch(part, timeout=0.5)
                    else:
                        self._stream_bus.send(part[0], timeout=0.5)
                except Exception as err:  # a full receive queue: the frame is lost, the receiver sees the gap
                    log.info("integrator: stream frame not sent: %s", err)

    # --- transport ------------------------------------------------------------------------------------
    def _serve(self) -> None:
        next_beat = time.monotonic()
        while not self._stop.is_set():
            msg = self._bus.recv(max(0.0, next_beat - time.monotonic()))  # a command, or the next beat's time
            now = time.monotonic()
            if now >= next_beat:
                next_beat = now + ci.HEARTBEAT_PERIOD_S
                if not self.faults.is_silent():
                    self._send(ci.heartbeat_id(self.node), bytes((0x05, self._status_bits())))
            if msg is None or msg.arbitration_id != ci.command_id(self.node) or self.faults.is_silent():
                continue
            reply = self.handle(bytes(msg.data))
            if not self.faults.before_reply():
                continue
            self._send(ci.reply_id(self.node), reply)
            self.faults.sent_reply()

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=1.0)
        self._bus.shutdown()
        if self._stream_bus is not self._bus:
            self._stream_bus.shutdown()
