"""Flux integrator over CAN / CAN FD (python-can), protocol from ``protocols.can_integrator``.

Commands and replies use one bus handle; the sample stream another (filtered to the stream's
identifier), so a reader thread never takes a command's reply.  Both are on ``channel`` (one bus
carries both, the controller or kernel filters each handle's frames) unless ``stream_channel``
names another: the emulated bench's, because python-can's virtual bus filters in Python, after
handing every handle every frame.  The stream carries the output
voltage as 24-bit codes, 17 to a CAN FD frame (``protocols.can_stream``); the driver divides by
the gain it read back, giving ``flux_Wb`` (flux through one turn).
"""

from __future__ import annotations

import time
from typing import TYPE_CHECKING, Any

from ..deadline import Deadline
from ..errors import ConfigError, InstrumentError, ProtocolError
from .base import Backoff, Instrument, InstrumentStatus
from .protocols import can_integrator as ci
from .stream import CanFrameSource, SampleStream

if TYPE_CHECKING:
    from .protocols.bench_config import BenchConfig, InstrumentConfig
    from .safety import CurrentBudget

__all__ = ["CanFluxIntegrator", "IntegratorError", "INTEGRATOR_STREAM_ID"]

INTEGRATOR_STREAM_ID = 4


class IntegratorError(InstrumentError):
    """The integrator refused a request (``result``, its result code), so a caller can tell a refused
    setting from a lost bus."""

    def __init__(self, message: str, result: int) -> None:
        super().__init__(message)
        self.result = result


class CanFluxIntegrator(Instrument):
    """The flux channel: requests on one CAN handle, the stream on another (module docstring)."""

    kind = "flux_integrator"

    def __init__(self, *, interface: str = "virtual", channel: str = "hystbench", node: int = 0x10,
                 fd: bool = True, bus_kwargs: dict | None = None, name: str | None = None,
                 timeout_s: float = 1.0, backoff: Backoff | None = None, fs_hz: float = 100_000.0,
                 stream_channel: str = "") -> None:
        super().__init__(name, timeout_s=timeout_s, backoff=backoff)
        if not 1 <= node <= 0x7F:
            raise ConfigError(f"{self.name}: node must be 1..127, got {node}")
        self.interface, self.channel, self.node, self.fd = interface, channel, node, fd
        self.stream_channel = stream_channel or channel
        self.bus_kwargs = dict(bus_kwargs or {})
        self.fs_hz = fs_hz
        self.firmware = ""
        self.settings: dict[str, Any] = {}
        self.last_heartbeat: tuple[float, int] | None = None  # (monotonic time, status bits)
        self._bus = None
        self._streams: list[SampleStream] = []

    @classmethod
    def from_config(cls, config: InstrumentConfig, bench: BenchConfig,
                    budget: CurrentBudget) -> "CanFluxIntegrator":
        o = config.options
        return cls(interface=o["interface"], channel=o["channel"], node=o["node"], fd=o["fd"],
                   stream_channel=o.get("stream_channel", ""), **cls._common(config, bench))

    def _new_bus(self, *can_ids: int, channel: str | None = None):
        """A bus handle on ``channel`` (default: the command channel) that takes only ``can_ids``
        (all when none are given): the command handle takes replies and heartbeats, so the 10 000
        stream frames a second are filtered out by the CAN controller or kernel (socketcan), not
        drained by the heartbeat in Python."""
        import can

        kw = dict(self.bus_kwargs)
        if can_ids:
            kw["can_filters"] = [{"can_id": i, "can_mask": 0x7FF, "extended": False} for i in can_ids]
        ch = channel or self.channel
        try:
            return can.Bus(interface=self.interface, channel=ch, receive_own_messages=False, fd=self.fd, **kw)
        except (can.CanInterfaceNotImplementedError, ImportError, ValueError) as err:  # not there to retry
            raise ConfigError(f"{self.name}: interface {self.interface!r}, channel {ch!r}: python-can cannot open it "
                              f"({type(err).__name__}: {err}); check [flux_integrator] interface and channel") from err
        except OSError as err:  # a CAN device that is not up (yet): reopened with back-off, said by name
            raise OSError(err.errno, f"{self.name}: CAN interface {self.interface!r}, channel {ch!r}: "
                                     f"{err.strerror or err}") from err

    # --- hooks -----------------------------------------------------------------------------------
    def _open_hook(self) -> None:
        self._bus = self._new_bus(ci.reply_id(self.node), ci.heartbeat_id(self.node))
        ident = self.call("identify")
        if ident >> 16 != ci.DEVICE_TYPE:
            raise ProtocolError(f"{self.name}: node 0x{self.node:02x} is device type 0x{ident >> 16:04x}, "
                                f"expected 0x{ci.DEVICE_TYPE:04x}")
        self.firmware = f"{(ident >> 8) & 0xFF}.{ident & 0xFF}"
        self.settings = {"gain_v_per_wb": self.call("get_gain"), "turns": self.call("get_turns")}

    def _close_hook(self) -> None:
        if self._bus is not None:
            try:
                self.call("stream", 0)
            except InstrumentError:
                pass
            self._bus.shutdown()
            self._bus = None

    def _configure_hook(self, key: str, value: Any) -> None:
        setters = {"gain_v_per_wb": self.set_gain, "turns": self.set_turns, "hold": self.hold}
        if key not in setters:
            raise ConfigError(f"{self.name}: no setting {key!r}; settings: {', '.join(setters)}")
        setters[key](value)

    def _status_hook(self) -> InstrumentStatus:
        return self.read_status()

    # --- public API --------------------------------------------------------------------------------
    def call(self, name: str, value: float | int | None = None) -> Any:
        """One request/reply exchange; IntegratorError if the integrator refuses it."""
        self._require_open(name)
        op = ci.OPS[name]
        if op.value != "none" and (value is None or (op.minimum is not None and value < op.minimum)
                                   or (op.maximum is not None and value > op.maximum)):
            raise ConfigError(f"{self.name}: refused {name} {value!r}: outside [{op.minimum}, {op.maximum}]")
        return self._io(f"{name}(0x{op.code:02x})", lambda: self._exchange(name, value))

    def reset(self) -> None:
        self.call("reset")

    def hold(self, on: bool = True) -> None:
        self.call("hold", int(bool(on)))

    def set_gain(self, gain_v_per_wb: float) -> None:
        self.settings["gain_v_per_wb"] = self.call("set_gain", float(gain_v_per_wb))
        for s in self._streams:
            s.scale["flux_Wb"] = 1.0 / self.settings["gain_v_per_wb"]

    def set_turns(self, turns: int) -> None:
        self.settings["turns"] = self.call("set_turns", int(turns))

    def read_status(self) -> InstrumentStatus:
        bits = self.call("get_status")
        faults = ("OVERLOAD",) if bits & ci.STATUS["OVERLOAD"] else ()
        values = {"integrating": bool(bits & ci.STATUS["INTEGRATING"]), "hold": bool(bits & ci.STATUS["HOLD"]),
                  "streaming": bool(bits & ci.STATUS["STREAMING"]), **self.settings}
        if self.last_heartbeat is not None:
            values["heartbeat_age_s"] = time.monotonic() - self.last_heartbeat[0]
        return InstrumentStatus(self.name, ok=not faults, faults=faults, values=values)

    def open_stream(self, *, stall_timeout_s: float = 0.5, backoff: Backoff | None = None,
                    skew_s: float = 0.0) -> SampleStream:
        """``flux_Wb`` on the common sample clock from CAN FD frames (wire: volts / gain)."""
        bus = self._new_bus(ci.stream_id(self.node), channel=self.stream_channel)
        source = _OwnedCanSource(bus, ci.stream_id(self.node), stream_id=INTEGRATOR_STREAM_ID)
        self.call("stream", 1)
        gain = self.call("get_gain")
        self.settings["gain_v_per_wb"] = gain
        stream = SampleStream(self.name, source, ["flux_Wb"], self.fs_hz, scale={"flux_Wb": 1.0 / gain},
                              skew_s=skew_s, stall_timeout_s=stall_timeout_s, backoff=backoff or self.backoff)
        try:
            stream.start()
        except Exception:
            bus.shutdown()
            raise
        self._streams.append(stream)
        return stream

    # --- internals ---------------------------------------------------------------------------------
    def _exchange(self, name: str, value: float | int | None) -> Any:
        import can

        if self._bus is None:
            raise ConnectionError("bus is not open")
        op = ci.OPS[name]
        self._bus.send(can.Message(arbitration_id=ci.command_id(self.node), data=ci.encode_command(name, value),
                                   is_extended_id=False), timeout=self.timeout_s)
        deadline = Deadline(self.timeout_s)
        while True:
            if deadline.expired:
                raise TimeoutError(name)
            msg = self._bus.recv(deadline.left())
            if msg is None:
                continue
            if msg.arbitration_id == ci.heartbeat_id(self.node) and len(msg.data) >= 2:
                self.last_heartbeat = (time.monotonic(), msg.data[1])
                continue
            if msg.arbitration_id != ci.reply_id(self.node):
                continue
            code, result, reply = ci.decode_reply(bytes(msg.data), name)
            if code != op.code:
                continue  # a late reply to an earlier request
            if result != 0:
                raise IntegratorError(f"{self.name}: {name}({value!r}) -> result {result} "
                                      f"({ci.RESULTS.get(result, '?')})", result)
            return reply


class _OwnedCanSource(CanFrameSource):
    """A CAN frame source that owns its bus handle and shuts it down when the stream closes."""

    def shutdown(self) -> None:
        self.bus.shutdown()
