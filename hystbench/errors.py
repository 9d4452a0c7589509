"""One exception tree for the whole service, drawn here once (every class the package defines;
``tests/test_errors.py`` fails when one is missing from this drawing or off the tree).

    BenchError                           hystbench.errors: the base; the CLI prints it, exit 2
     ├── ConfigError                     a preset, bench file, daemon file, command-line value or command
     │                                   argument is wrong (names the file/key/option); config/, physics/
     │                                   presets, sim_backend/, acquisition/ (bench_commands, daemon,
     │                                   sources, stages), cli/   (also a ValueError)
     ├── RecordingError                  a recording or log cannot be read or written (names file/line/
     │    │                              column); formats/, analysis/identification, acquisition/record (a
     │    │                              record or replay whose pipeline failed), cli/   (also ValueError)
     │    └── LogWriteError              formats/mcaplog/recorder: the disk refused a write (full, I/O
     │                                   error, read-only); names the part, the folder and its free space
     ├── EstimationError                 the data cannot give the asked-for estimate (names the recording);
     │                                   analysis/   (also a ValueError)
     ├── DiagnosisError                  a bench day the diagnosis cannot take: one recording, mixed sample
     │                                   rates in one rig, a rig no preset simulates (names the recording);
     │                                   analysis/diagnosis   (also a ValueError)
     ├── SimulationError                 the simulated rig cannot follow what it was asked (names rig and
     │                                   why); sim_backend/actuators/ecore, cli/main (a clipped ADC)
     ├── CommandRefused                  a command the bench cannot carry out now: not running, a sweep is
     │                                   running, the compensator switched the output off, the source takes
     │                                   no commands (service/service, acquisition/zenoh_bus); on the
     │                                   client side (service/control, acquisition/zenoh_bus.send_command)
     │                                   any ``ok: false`` reply, with the daemon's ``reply``
     ├── TooManyFaults                   service/service: faults in quick succession, the service stops
     │                                   (the daemon exits 1; the last fault is the ``__cause__``)
     ├── NetworkError                    the zenoh network: an endpoint, a reply
     │    ├── ListenError                acquisition/zenoh_bus.open_session: a listen endpoint is taken
     │    └── NoReply                    nobody answered a command or query in time; service/control,
     │                                   acquisition/zenoh_bus.send_command   (also a TimeoutError)
     ├── InstrumentError                 an instrument misbehaves (names the instrument and command)
     │    ├── ConnectionLost             drivers/base, drivers/stream   (also a ConnectionError)
     │    ├── ProtocolError              an answer the protocol does not allow; drivers/base, the drivers'
     │    │    │                         identification checks
     │    │    └── FrameError            drivers/protocols/framing: bytes that are no valid sample frame
     │    │                              (also a ValueError)
     │    ├── InstrumentTimeout          drivers/base, drivers/bench (aligned acquisition)   (also a
     │    │                              TimeoutError)
     │    ├── ScpiError                  drivers/signal_generator: the generator's error queue
     │    ├── ModbusError                drivers/current_amplifier: a Modbus exception response
     │    ├── ModbusException            drivers/protocols/modbus_map: an emulated register refuses a
     │    │                              request (the server answers it as an exception response)
     │    ├── ChargeAmpError             drivers/charge_amplifier: the amplifier's error reply
     │    ├── IntegratorError            drivers/flux_integrator: the integrator's result code
     │    ├── SafetyLimitError           drivers/safety: a command would exceed the current limit
     │    │                              (also a ValueError)
     │    └── FaultLatched               drivers/current_amplifier: the amplifier reports latched fault
     │                                   bits; drivers/bench acts on it at once (defined in drivers/base)
     └── CompensatorError                compensator/: a force model or the loop cannot do what was asked
          ├── UnreachableReference       compensator/static, learning: a force beyond the actuator
          │                              (also a ValueError)
          └── LearningStopped            compensator/learning: the loop stopped itself, output off

Every message names what is at fault; code that converts a lower-level error raises ``... from err``.
A refusal at run time is a :class:`CommandRefused`, never a :class:`ConfigError`: nothing in the
files or options is wrong, the bench is busy or off.  The extra bases (``ValueError``,
``TimeoutError``) keep older ``except`` clauses working; new code catches the tree's classes.
"""

from __future__ import annotations

import sys
from typing import Any, Callable, Mapping


class BenchError(Exception):
    """Base of every error this service raises on purpose."""


class ConfigError(BenchError, ValueError):
    """A configuration value is missing or invalid."""


class RecordingError(BenchError, ValueError):
    """A recording (CSV+JSON, MCAP) is missing, malformed or inconsistent."""


class LogWriteError(RecordingError):
    """The log's folder refused a write (ENOSPC, EIO, EROFS ...): not the data's fault, and over
    once space is back.  ``errno`` is the OS's; ``folder`` where the log was going."""

    def __init__(self, message: str, *, errno: int | None = None, folder: str = "") -> None:
        super().__init__(message)
        self.errno, self.folder = errno, folder


class EstimationError(BenchError, ValueError):
    """The data cannot support the requested estimate."""


class SimulationError(BenchError):
    """The simulated rig was driven outside the range its physics is solved in."""


class CommandRefused(BenchError):
    """The bench refused a command it cannot carry out in its present state (the same command may
    succeed later).  ``reply`` is the daemon's ``{"ok": false, "error": ...}`` when the refusal
    came over zenoh, else empty."""

    def __init__(self, message: str, reply: Mapping[str, Any] | None = None) -> None:
        super().__init__(message)
        self.reply = dict(reply or {})


class NetworkError(BenchError):
    """The zenoh network would not carry a request: an endpoint cannot be bound, nobody answers."""


class NoReply(NetworkError, TimeoutError):
    """Nobody answered a command or query within its timeout."""


class InstrumentError(BenchError):
    """An instrument did not do what it was asked."""


class ConnectionLost(InstrumentError, ConnectionError):
    """The transport to an instrument went away."""


class ProtocolError(InstrumentError):
    """An instrument answered something the protocol does not allow."""


class InstrumentTimeout(InstrumentError, TimeoutError):
    """An instrument did not answer in time."""


__all__ = [
    "script_status",
    "BenchError",
    "ConfigError",
    "RecordingError",
    "LogWriteError",
    "EstimationError",
    "SimulationError",
    "CommandRefused",
    "NetworkError",
    "NoReply",
    "InstrumentError",
    "ConnectionLost",
    "ProtocolError",
    "InstrumentTimeout",
]


def script_status(main: Callable[[], int]) -> int:
    """A module run as a script (``python -m ...``): ``main``'s status, or a BenchError (a bad file,
    named by the error) as one line on stderr and status 2, never a traceback."""
    try:
        return main()
    except BenchError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
