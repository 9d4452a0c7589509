"""Signal generator over SCPI (serial port or ``socket://host:port``), commands from one table.

After every configuration command the driver reads ``SYST:ERR?``; a non-zero entry becomes a
:class:`ScpiError` naming the command, after the queue is drained.  Amplitude, offset and waveform
changes are checked against the shared :class:`CurrentBudget` before anything is sent, and a
sine change is ordered so that no intermediate setting exceeds it either.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, Mapping

import numpy as np

from ..errors import ConfigError, InstrumentError, ProtocolError
from .base import Backoff, Instrument, InstrumentStatus
from .protocols import scpi
from .protocols.scpi import GENERATOR
from .safety import CurrentBudget
from .stream import SampleStream, frame_source
from .transport import SerialLink

if TYPE_CHECKING:
    from .protocols.bench_config import BenchConfig, InstrumentConfig

__all__ = ["ScpiSignalGenerator", "ScpiError", "GENERATOR_STREAM_ID"]

GENERATOR_STREAM_ID = 1  #: stream id of the command_V stream
_MAX_ERRORS = 32  # bound on draining the error queue


class ScpiError(InstrumentError):
    """The generator put an error in its queue; ``errors`` holds every (code, text) drained."""

    def __init__(self, message: str, errors: list[tuple[int, str]]) -> None:
        super().__init__(message)
        self.errors = errors


class ScpiSignalGenerator(Instrument):
    """The excitation: sines and arbitrary tables over SCPI, every change checked against the budget."""

    kind = "signal_generator"

    def __init__(self, url: str, *, budget: CurrentBudget, name: str | None = None, timeout_s: float = 1.0,
                 backoff: Backoff | None = None, baudrate: int = 115200, reset_on_open: bool = True,
                 stream_url: str | None = None, fs_hz: float = 100_000.0) -> None:
        super().__init__(name, timeout_s=timeout_s, backoff=backoff)
        self.link = SerialLink(url, baudrate=baudrate, timeout_s=timeout_s, eol=b"\n")
        self.budget = budget
        self.reset_on_open = reset_on_open
        self.stream_url, self.fs_hz = stream_url, fs_hz
        self.identity: dict[str, str] = {}
        self.state: dict[str, Any] = {}

    @classmethod
    def from_config(cls, config: InstrumentConfig, bench: BenchConfig,
                    budget: CurrentBudget) -> "ScpiSignalGenerator":
        o = config.options
        if not o["url"]:
            raise ConfigError(f"{bench.source} [{config.name}]: no url (start the emulators or set one)")
        return cls(o["url"], budget=budget, baudrate=o["baudrate"], reset_on_open=o["reset_on_open"],
                   stream_url=o["stream_url"] or None, **cls._common(config, bench))

    def setup(self, settings: Mapping[str, Any]) -> None:
        """The file's frequency, amplitude and offset as one sine (changed in the order that stays
        within the current budget), the others as found."""
        if settings:
            s = {**self.state, **settings}
            self.set_sine(s["frequency_hz"], s["amplitude_vpp"], s["offset_v"])

    def heartbeat(self) -> None:
        self.query("output")  # one short query: the full status drains the error queue too

    # --- hooks -----------------------------------------------------------------------------------
    def _open_hook(self) -> None:
        self.link.open()
        fields = [f.strip() for f in self._query_raw("identity").split(",")]
        if len(fields) != len(scpi.IDN_FIELDS):
            raise ProtocolError(f"{self.name}: *IDN? answer {','.join(fields)!r} does not have "
                                f"{len(scpi.IDN_FIELDS)} fields")
        self.identity = dict(zip(scpi.IDN_FIELDS, fields))
        if self.reset_on_open:
            self._send("reset")
            self._send("clear_status")
            self._check_errors("*RST/*CLS")
        self.state = {k: self.query(k) for k in ("function", "frequency_hz", "amplitude_vpp", "offset_v", "output")}
        self.budget.commit_command(self._peak_v(self.state["amplitude_vpp"], self.state["offset_v"]))

    def _close_hook(self) -> None:
        self.link.close()

    def _safe_off_hook(self) -> None:
        if not self.link.is_open:
            raise InstrumentError(f"{self.name}: link is closed; cannot send OUTP OFF")
        self._send("output", False)
        if self.query("output"):
            raise InstrumentError(f"{self.name}: output still on after OUTP OFF")
        self.state["output"] = False

    def _configure_hook(self, key: str, value: Any) -> None:
        if key in ("frequency_hz", "amplitude_vpp", "offset_v", "function"):
            self.set(key, value)
        elif key == "output":
            self.set_output(bool(value))
        else:
            raise ConfigError(f"{self.name}: no setting {key!r}; settings: frequency_hz, amplitude_vpp, "
                              f"offset_v, function, output")

    def _status_hook(self) -> InstrumentStatus:
        errors = self._drain_errors()
        values = {k: self.query(k) for k in ("function", "frequency_hz", "amplitude_vpp", "offset_v", "output")}
        self.state.update(values)
        return InstrumentStatus(self.name, ok=not errors, faults=tuple(f"{c},{t}" for c, t in errors), values=values)

    # --- public API --------------------------------------------------------------------------------
    def query(self, name: str) -> Any:
        """Read one property of the command table (``frequency_hz``, ``output``, ...)."""
        self._require_open(f"query {name}")
        return self._io(GENERATOR[name].short + "?", lambda: GENERATOR[name].parse(self._query_raw(name)))

    def set(self, name: str, value: Any) -> None:
        """Write one property, checked against the table's range and the current budget first."""
        self._require_open(f"set {name}")
        ctl = GENERATOR[name]
        try:
            ctl.check(name, value)
        except ValueError as err:
            raise ConfigError(f"{self.name}: refused {ctl.short} {value!r}: {err}") from err
        if name in ("amplitude_vpp", "offset_v"):
            amp = value if name == "amplitude_vpp" else self.state["amplitude_vpp"]
            off = value if name == "offset_v" else self.state["offset_v"]
            peak = self._peak_v(amp, off)
            self.budget.check_command(self.name, f"{ctl.short} {ctl.format(value)}", peak)
        self._send(name, value)
        self._check_errors(f"{ctl.short} {ctl.format(value)}")
        self.state[name] = ctl.parse(ctl.format(value)) if ctl.kind != "float" else float(value)
        if name in ("amplitude_vpp", "offset_v"):
            self.budget.commit_command(self._peak_v(self.state["amplitude_vpp"], self.state["offset_v"]))

    def set_output(self, on: bool) -> None:
        self.set("output", bool(on))

    def set_sine(self, frequency_hz: float, amplitude_vpp: float, offset_v: float = 0.0) -> None:
        """Sine at these settings; amplitude and offset change in the order that stays in budget."""
        self._require_open("set_sine")
        self.budget.check_command(self.name, f"sine {amplitude_vpp:g} Vpp {offset_v:+g} V",
                                  self._peak_v(amplitude_vpp, offset_v))
        for name, value in [("frequency_hz", frequency_hz), *self._safe_order(amplitude_vpp, offset_v)]:
            self.set(name, value)
        if self.state.get("function") != "SIN":
            self.set("function", "SIN")

    def upload_waveform(self, volts: np.ndarray, frequency_hz: float) -> None:
        """Play one period of ``volts`` (uniformly sampled) at ``frequency_hz`` (the compensator's
        output).  The table is normalised to the DAC's [-1, 1] with amplitude and offset set so that
        the output is ``volts`` again; its peak is checked against the budget first."""
        self._require_open("upload_waveform")
        v = np.asarray(volts, dtype=float)
        if v.ndim != 1 or not scpi.ARB_POINTS[0] <= v.size <= scpi.ARB_POINTS[1] or not np.all(np.isfinite(v)):
            raise ConfigError(f"{self.name}: waveform must be 1-D, finite, {scpi.ARB_POINTS[0]}.."
                              f"{scpi.ARB_POINTS[1]} points; got shape {v.shape}")
        hi, lo = float(v.max()), float(v.min())
        offset, vpp = (hi + lo) / 2.0, hi - lo
        self.budget.check_command(self.name, f"DATA:ARB:DAC ({v.size} points, peak {max(abs(hi), abs(lo)):.4g} V)",
                                  max(abs(hi), abs(lo)))
        unit = (v - offset) / (vpp / 2.0) if vpp > 0 else np.zeros_like(v)
        block = scpi.dac_from_unit(np.clip(unit, -1.0, 1.0))
        self._send("arb_dac", block)
        self._check_errors(f"DATA:ARB:DAC #{len(str(len(block)))}{len(block)}...")
        self.set("frequency_hz", frequency_hz)
        for name, value in self._safe_order(vpp, offset):
            self.set(name, value)
        self.set("function", "ARB")

    def read_error(self) -> tuple[int, str]:
        """The oldest entry of the error queue (0, 'No error') when empty."""
        self._require_open("read_error")
        return self._io("SYST:ERR?", lambda: scpi.parse_error_reply(self._query_raw("error")))

    def open_stream(self, *, stall_timeout_s: float = 0.5, backoff: Backoff | None = None,
                    skew_s: float = 0.0) -> SampleStream:
        """The generator's output monitor (``command_V``) on the common sample clock."""
        if not self.stream_url:
            raise ConfigError(f"{self.name}: no stream_url configured")
        source = frame_source(self.stream_url, GENERATOR_STREAM_ID)
        return SampleStream(self.name, source, ["command_V"], self.fs_hz, skew_s=skew_s,
                            stall_timeout_s=stall_timeout_s, backoff=backoff or self.backoff).start()

    # --- internals ---------------------------------------------------------------------------------
    @staticmethod
    def _peak_v(amplitude_vpp: float, offset_v: float) -> float:
        return abs(float(offset_v)) + float(amplitude_vpp) / 2.0

    def _safe_order(self, amplitude_vpp: float, offset_v: float) -> list[tuple[str, float]]:
        """Amplitude first unless that intermediate state would exceed the budget's peak."""
        limit = self.budget.command_limit_a / self.budget.gain_a_per_v
        if self._peak_v(amplitude_vpp, self.state["offset_v"]) <= limit:
            return [("amplitude_vpp", amplitude_vpp), ("offset_v", offset_v)]
        return [("offset_v", offset_v), ("amplitude_vpp", amplitude_vpp)]

    def _send(self, name: str, value: Any = None) -> None:
        ctl = GENERATOR[name]
        self._io(ctl.short, lambda: self.link.write(ctl.set_command(value)))

    def _query_raw(self, name: str) -> str:
        ctl = GENERATOR[name]

        def ask() -> str:
            self.link.reset_input()
            self.link.write(ctl.query_command())
            return self.link.read_line().decode("ascii", "replace").strip()
        return self._io(ctl.short + "?", ask)

    def _drain_errors(self) -> list[tuple[int, str]]:
        errors: list[tuple[int, str]] = []
        for _ in range(_MAX_ERRORS):
            code, text = self._io("SYST:ERR?", lambda: scpi.parse_error_reply(self._query_raw("error")))
            if code == 0:
                break
            errors.append((code, text))
        return errors

    def _check_errors(self, command: str) -> None:
        errors = self._drain_errors()
        if errors:
            listed = "; ".join(f'{c},"{t}"' for c, t in errors)
            raise ScpiError(f"{self.name}: {command!r} -> {listed}", errors)
