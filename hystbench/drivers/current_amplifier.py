"""Current amplifier over Modbus TCP or RTU (pymodbus 3.x sync clients), register map from
``protocols.modbus_map``.

Gain and current-limit writes are checked against the shared :class:`CurrentBudget` first.  The
amplifier's communication watchdog disables its output when the host falls silent; the bench keeps
it fed by polling :meth:`read_status`.  Exception responses become :class:`ModbusError` naming the
register and the exception.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from ..errors import ConfigError, InstrumentError, InstrumentTimeout, ProtocolError
from .base import Backoff, FaultLatched, Instrument, InstrumentStatus
from .protocols.modbus_map import CONTROL, EXCEPTIONS, FAULTS, MODEL_ID, REGISTERS, STATUS
from .safety import CurrentBudget
from .stream import SampleStream, frame_source

if TYPE_CHECKING:
    from .protocols.bench_config import BenchConfig, InstrumentConfig

__all__ = ["ModbusCurrentAmplifier", "ModbusError", "AMPLIFIER_STREAM_ID"]

AMPLIFIER_STREAM_ID = 2  #: stream id of the current_A monitor stream
_STATUS_SPAN = ("control", "status", "faults", "gain", "current_limit", "watchdog", "current",
                "current_rms", "temperature")


class ModbusError(InstrumentError):
    """The amplifier answered with a Modbus exception."""

    def __init__(self, message: str, code: int) -> None:
        super().__init__(message)
        self.code = code


def _bits(value: int, table) -> tuple[str, ...]:
    return tuple(name for name, bit in table.items() if value & bit)


class ModbusCurrentAmplifier(Instrument):
    """The coil current: its gate (enable), gain and limit over Modbus, within the shared budget."""

    kind = "current_amplifier"
    gate = True  # disabled, no coil current whatever the generator plays

    def __init__(self, *, budget: CurrentBudget, host: str | None = None, port: int = 502,
                 serial_port: str | None = None, baudrate: int = 19200, unit: int = 1,
                 name: str | None = None, timeout_s: float = 1.0, backoff: Backoff | None = None,
                 stream_url: str | None = None, fs_hz: float = 100_000.0) -> None:
        super().__init__(name, timeout_s=timeout_s, backoff=backoff)
        if (host is None) == (serial_port is None):
            raise ConfigError(f"{self.name}: give exactly one of host (Modbus TCP) or serial_port (Modbus RTU)")
        if not 1 <= unit <= 247:
            raise ConfigError(f"{self.name}: unit must be 1..247, got {unit}")
        self.host, self.port, self.serial_port, self.baudrate, self.unit = host, port, serial_port, baudrate, unit
        self.budget = budget
        self.stream_url, self.fs_hz = stream_url, fs_hz
        self.firmware = ""
        self._client = None

    @classmethod
    def from_config(cls, config: InstrumentConfig, bench: BenchConfig,
                    budget: CurrentBudget) -> "ModbusCurrentAmplifier":
        o = config.options
        where = dict(host=o["host"], port=o["port"]) if o["transport"] == "tcp" else dict(
            serial_port=o["serial_port"], baudrate=o["baudrate"])
        return cls(budget=budget, unit=o["unit"], stream_url=o["stream_url"] or None, **where,
                   **cls._common(config, bench))

    def heartbeat(self) -> None:
        """Read the status (which feeds the watchdog); a latched fault has already disabled the output."""
        st = self.read_status()
        if st.faults:
            raise FaultLatched(f"{self.name}: fault {', '.join(st.faults)}; output disabled by the amplifier",
                               tuple(st.faults))

    def _make_client(self):
        from pymodbus.client import ModbusSerialClient, ModbusTcpClient

        if self.host is not None:
            return ModbusTcpClient(self.host, port=self.port, timeout=self.timeout_s, retries=0)
        return ModbusSerialClient(self.serial_port, baudrate=self.baudrate, timeout=self.timeout_s, retries=0)

    # --- hooks -----------------------------------------------------------------------------------
    def _open_hook(self) -> None:
        self._client = self._make_client()
        where = f"{self.host}:{self.port}" if self.host else self.serial_port
        if not self._client.connect():
            raise ConnectionError(f"cannot connect to Modbus {'TCP' if self.host else 'RTU'} at {where}")
        model, fw = self._read_raw("model_id", 2)
        if model != MODEL_ID:
            raise ProtocolError(f"{self.name}: register 0 (model id) is 0x{model:04X}, expected 0x{MODEL_ID:04X}")
        self.firmware = f"{fw >> 8}.{fw & 0xFF}"
        gain = self.read("gain")
        self.budget.check_gain(self.name, "gain as found at open", gain)
        self.budget.commit_gain(gain)

    def _close_hook(self) -> None:
        if self._client is not None:
            self._client.close()
            self._client = None

    def _safe_off_hook(self) -> None:
        if self._client is None:
            raise InstrumentError(f"{self.name}: not connected; cannot disable")
        self._write_raw("control", [0])
        if self._read_raw("status", 1)[0] & STATUS["ENABLED"]:
            raise InstrumentError(f"{self.name}: still enabled after writing control = 0")

    def _configure_hook(self, key: str, value: Any) -> None:
        setters = {"gain_a_per_v": self.set_gain, "current_limit_a": self.set_current_limit,
                   "watchdog_s": self.set_watchdog, "enabled": lambda v: self.enable() if v else self.disable()}
        if key not in setters:
            raise ConfigError(f"{self.name}: no setting {key!r}; settings: {', '.join(setters)}")
        setters[key](value)

    def _status_hook(self) -> InstrumentStatus:
        return self.read_status()

    # --- public API --------------------------------------------------------------------------------
    def read(self, name: str) -> float:
        """One register in SI units (A/V, A, s, degC ...)."""
        return REGISTERS[name].to_si(self._read_raw(name, 1)[0])

    def write(self, name: str, value: float) -> None:
        reg = REGISTERS[name]
        if reg.access != "RW":
            raise ConfigError(f"{self.name}: register {reg.address} ({name}) is read-only")
        try:
            raw = reg.to_raw(value)
        except ValueError as err:
            raise ConfigError(f"{self.name}: refused write of register {reg.address}: {err}") from err
        self._write_raw(name, [raw])

    def set_gain(self, gain_a_per_v: float) -> None:
        self.budget.check_gain(self.name, f"write gain (register {REGISTERS['gain'].address}) = {gain_a_per_v:g} A/V",
                               gain_a_per_v)
        self.write("gain", gain_a_per_v)
        self.budget.commit_gain(self.read("gain"))

    def set_current_limit(self, limit_a: float) -> None:
        self.budget.check_limit(self.name, f"write current_limit (register {REGISTERS['current_limit'].address})"
                                f" = {limit_a:g} A", limit_a)
        self.write("current_limit", limit_a)
        reg = REGISTERS["current_limit"]
        self.budget.commit_limit(reg.to_si(reg.to_raw(limit_a)))  # the trip level, as the register holds it

    def set_watchdog(self, timeout_s: float) -> None:
        self.write("watchdog", timeout_s)

    def enable(self) -> None:
        self._write_raw("control", [CONTROL["ENABLE"]])

    def disable(self) -> None:
        self._write_raw("control", [0])

    def clear_faults(self) -> None:
        """Clear latched faults; the output stays disabled until enabled again."""
        self._write_raw("control", [CONTROL["CLEAR_FAULTS"]])

    def read_status(self) -> InstrumentStatus:
        """Status, latched faults and telemetry in one request (also feeds the watchdog)."""
        raw = dict(zip(_STATUS_SPAN, self._read_raw(_STATUS_SPAN[0], len(_STATUS_SPAN))))
        values: dict[str, Any] = {
            "enabled": bool(raw["status"] & STATUS["ENABLED"]),
            "gain_a_per_v": REGISTERS["gain"].to_si(raw["gain"]),
            "current_limit_a": REGISTERS["current_limit"].to_si(raw["current_limit"]),
            "watchdog_s": REGISTERS["watchdog"].to_si(raw["watchdog"]),
            "current_a": REGISTERS["current"].to_si(raw["current"]),
            "current_rms_a": REGISTERS["current_rms"].to_si(raw["current_rms"]),
            "temperature_c": REGISTERS["temperature"].to_si(raw["temperature"]),
        }
        faults = _bits(raw["faults"], FAULTS)
        return InstrumentStatus(self.name, ok=not faults and not raw["status"] & STATUS["FAULT"],
                                faults=faults, values=values)

    def open_stream(self, *, stall_timeout_s: float = 0.5, backoff: Backoff | None = None,
                    skew_s: float = 0.0) -> SampleStream:
        """The output current monitor (``current_A``, amperes) on the common sample clock."""
        if not self.stream_url:
            raise ConfigError(f"{self.name}: no stream_url configured")
        source = frame_source(self.stream_url, AMPLIFIER_STREAM_ID)
        return SampleStream(self.name, source, ["current_A"], self.fs_hz, skew_s=skew_s,
                            stall_timeout_s=stall_timeout_s, backoff=backoff or self.backoff).start()

    # --- internals ---------------------------------------------------------------------------------
    def _guarded(self, what: str, call):
        """Run one request; after a timeout drop the connection, so that a late reply still in
        the socket cannot be taken for the answer to the next request (pymodbus reconnects)."""
        try:
            return self._io(what, call)
        except InstrumentTimeout:
            if self._client is not None:
                self._client.close()
            raise

    def _check(self, rr, what: str):
        if rr.isError():
            code = getattr(rr, "exception_code", 0)
            raise ModbusError(f"{self.name}: {what} -> Modbus exception {code} ({EXCEPTIONS.get(code, '?')})", code)
        return rr

    def _read_raw(self, first: str, count: int) -> list[int]:
        address = REGISTERS[first].address
        what = f"read {count} register(s) from {address} ({first})"
        self._require_open(what)

        def call() -> list[int]:
            if self._client is None:
                raise ConnectionError("not connected")
            rr = self._check(self._client.read_holding_registers(address, count=count, device_id=self.unit), what)
            if len(rr.registers) != count:
                raise ProtocolError(f"{self.name}: {what}: got {len(rr.registers)} registers")
            return list(rr.registers)
        return self._guarded(what, call)

    def _write_raw(self, first: str, values: list[int]) -> None:
        address = REGISTERS[first].address
        what = f"write {first} (register {address}) = {values[0] if len(values) == 1 else values}"
        self._require_open(what)

        def call() -> None:
            if self._client is None:
                raise ConnectionError("not connected")
            if len(values) == 1:
                self._check(self._client.write_register(address, values[0], device_id=self.unit), what)
            else:
                self._check(self._client.write_registers(address, values, device_id=self.unit), what)
        self._guarded(what, call)
