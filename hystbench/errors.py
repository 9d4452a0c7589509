"""One exception tree for the whole service.

    BenchError
     ├── ConfigError            a preset, bench file or command-line value is wrong (names the key)
     ├── RecordingError         a recording or log cannot be read or written (names file/line/column)
     ├── EstimationError        the data cannot give the asked-for estimate (names the recording)
     ├── SimulationError        the simulated rig cannot follow what it was asked (names rig and why)
     └── InstrumentError        an instrument misbehaves (names the instrument and command)
          ├── ConnectionLost
          ├── ProtocolError
          └── InstrumentTimeout  (also a TimeoutError)

Every message names what is at fault; code that converts a lower-level error raises ``... from err``.
"""

from __future__ import annotations


class BenchError(Exception):
    """Base of every error this service raises on purpose."""


class ConfigError(BenchError, ValueError):
    """A configuration value is missing or invalid."""


class RecordingError(BenchError, ValueError):
    """A recording (CSV+JSON, MCAP) is missing, malformed or inconsistent."""


class EstimationError(BenchError, ValueError):
    """The data cannot support the requested estimate."""


class SimulationError(BenchError):
    """The simulated rig was driven outside the range its physics is solved in."""


class InstrumentError(BenchError):
    """An instrument did not do what it was asked."""


class ConnectionLost(InstrumentError, ConnectionError):
    """The transport to an instrument went away."""


class ProtocolError(InstrumentError):
    """An instrument answered something the protocol does not allow."""


class InstrumentTimeout(InstrumentError, TimeoutError):
    """An instrument did not answer in time."""


__all__ = [
    "BenchError",
    "ConfigError",
    "RecordingError",
    "EstimationError",
    "SimulationError",
    "InstrumentError",
    "ConnectionLost",
    "ProtocolError",
    "InstrumentTimeout",
]
