"""Charge amplifier (Kistler 5070 class) over RS-232 ASCII; every mnemonic from ``protocols.charge_amp``.

Its force stream carries the output voltage U_F (COBS frames on the stream port); the driver turns
it into newtons with the scale (N/V) it read back from the amplifier, so a scale change on the
instrument and the samples' units cannot disagree.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, Mapping

from ..errors import ConfigError, InstrumentError
from .base import Backoff, Instrument, InstrumentStatus, log
from .protocols.charge_amp import COMMANDS, ERRORS, OK, STATUS, parse_reply_error
from .stream import SampleStream, frame_source
from .transport import SerialLink

if TYPE_CHECKING:
    from .protocols.bench_config import BenchConfig, InstrumentConfig
    from .safety import CurrentBudget

__all__ = ["ChargeAmplifier", "ChargeAmpError", "CHARGE_AMP_STREAM_ID"]

CHARGE_AMP_STREAM_ID = 3
_SETTINGS = ("sensitivity_pc_per_n", "scale_n_per_v", "time_constant", "lowpass_hz")


class ChargeAmpError(InstrumentError):
    """The amplifier answered a command with an error code (``code``, its E-number), so a caller can
    tell a refused setting from a lost link."""

    def __init__(self, message: str, code: int) -> None:
        super().__init__(message)
        self.code = code


class ChargeAmplifier(Instrument):
    """The force channel: settings over RS-232 ASCII, the force stream in newtons (module docstring)."""

    kind = "charge_amplifier"

    def __init__(self, url: str, *, name: str | None = None, timeout_s: float = 1.0,
                 backoff: Backoff | None = None, baudrate: int = 115200, stream_url: str | None = None,
                 fs_hz: float = 100_000.0) -> None:
        super().__init__(name, timeout_s=timeout_s, backoff=backoff)
        self.link = SerialLink(url, baudrate=baudrate, timeout_s=timeout_s, eol=b"\r")
        self.stream_url, self.fs_hz = stream_url, fs_hz
        self.identity = ""
        self.settings: dict[str, Any] = {}
        self._streams: list[SampleStream] = []

    @classmethod
    def from_config(cls, config: InstrumentConfig, bench: BenchConfig,
                    budget: CurrentBudget) -> "ChargeAmplifier":
        o = config.options
        return cls(o["url"], baudrate=o["baudrate"], stream_url=o["stream_url"] or None,
                   **cls._common(config, bench))

    def setup(self, settings: Mapping[str, Any]) -> None:
        """The file's settings, then OPERATE: a charge amplifier measures only there."""
        super().setup(settings)
        self.operate()

    def heartbeat(self) -> None:
        """An overload is no fault of the bench: the force samples carry it (CLIP); say so."""
        if "OVERLOAD" in self.status().faults:
            log.warning("%s overload: force samples are flagged CLIP", self.name)

    # --- hooks -----------------------------------------------------------------------------------
    def _open_hook(self) -> None:
        self.link.open()
        self.identity = self.query("identity")
        self.settings = {k: self.query(k) for k in _SETTINGS}

    def _close_hook(self) -> None:
        self.link.close()

    def _configure_hook(self, key: str, value: Any) -> None:
        if key == "mode":
            self.operate() if str(value).upper() == "OPERATE" else self.reset()
        elif key in _SETTINGS:
            self.set(key, value)
        else:
            raise ConfigError(f"{self.name}: no setting {key!r}; settings: mode, {', '.join(_SETTINGS)}")

    def _status_hook(self) -> InstrumentStatus:
        bits = self.query("status")
        faults = tuple(n for n in ("OVERLOAD", "OVERLOAD_LATCHED") if bits & STATUS[n])
        values = {"operate": bool(bits & STATUS["OPERATE"]), **self.settings}
        return InstrumentStatus(self.name, ok=not faults, faults=faults, values=values)

    # --- public API --------------------------------------------------------------------------------
    def query(self, name: str) -> Any:
        self._require_open(f"query {name}")
        m = COMMANDS[name]
        text = self._exchange(m.query_command())
        code = parse_reply_error(text)
        if code is not None:
            raise ChargeAmpError(f"{self.name}: {m.query!r} -> E{code:02d} ({ERRORS.get(code, '?')})", code)
        return self._io(m.query or name, lambda: m.parse(text))

    def set(self, name: str, value: Any = None) -> None:
        """Send one setting (checked against the table first); the amplifier must answer OK."""
        self._require_open(f"set {name}")
        m = COMMANDS[name]
        try:
            m.check(name, value)
        except ValueError as err:
            raise ConfigError(f"{self.name}: refused {name}: {err}") from err
        cmd = m.set_command(value)
        text = self._exchange(cmd)
        shown = cmd.decode().strip()
        if text != OK:
            code = parse_reply_error(text)
            if code is None:
                raise InstrumentError(f"{self.name}: {shown!r} -> unexpected reply {text!r}")
            raise ChargeAmpError(f"{self.name}: {shown!r} -> E{code:02d} ({ERRORS.get(code, '?')})", code)
        if name in _SETTINGS:
            self.settings[name] = m.parse(m.format(value))
            if name == "scale_n_per_v":
                for s in self._streams:
                    s.scale["force_N"] = self.settings[name]

    def reset(self) -> None:
        self.set("reset")

    def operate(self) -> None:
        self.set("operate")

    def open_stream(self, *, stall_timeout_s: float = 0.5, backoff: Backoff | None = None,
                    skew_s: float = 0.0) -> SampleStream:
        """``force_N`` on the common sample clock (wire: volts; scaled by the read-back N/V)."""
        if not self.stream_url:
            raise ConfigError(f"{self.name}: no stream_url configured")
        self.settings["scale_n_per_v"] = self.query("scale_n_per_v")
        source = frame_source(self.stream_url, CHARGE_AMP_STREAM_ID)
        stream = SampleStream(self.name, source, ["force_N"], self.fs_hz,
                              scale={"force_N": self.settings["scale_n_per_v"]}, skew_s=skew_s,
                              stall_timeout_s=stall_timeout_s, backoff=backoff or self.backoff).start()
        self._streams.append(stream)
        return stream

    # --- internals ---------------------------------------------------------------------------------
    def _exchange(self, command: bytes) -> str:
        shown = command.decode().strip()

        def ask() -> str:
            self.link.reset_input()
            self.link.write(command)
            return self.link.read_line().decode("ascii", "replace").strip()
        return self._io(shown, ask)
