"""The common driver interface (python-can style): public methods own locking, timeouts, logging
and error translation once; each instrument overrides only private hooks.

    open() -> _open_hook()             close() -> safe_off() first, then _close_hook()
    configure(**s) -> _configure_hook() status() -> _status_hook()
    safe_off() -> _safe_off_hook()      reconnect() -> close quietly, reopen with Backoff

Every I/O goes through :meth:`Instrument._io`, which turns transport exceptions into the service's
tree (``InstrumentTimeout`` / ``ConnectionLost`` / ``ProtocolError``) naming instrument and command.

What the bench does with any instrument is here too, so that it needs no branch per instrument
(``drivers.BACKENDS`` names the class, the class builds itself):

    from_config(table, bench, budget)   the driver as the bench file describes it
    gate                                 True: opened first and disabled (no current whatever the others do)
    setup(settings)                      the file's settings, then the state the bench measures in
    heartbeat()                          the bench's periodic poll (raises FaultLatched on a latched fault)
"""

from __future__ import annotations

import abc
import logging
import socket
import threading
import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Callable, Iterator, Mapping, Self, TypeVar

from ..errors import ConfigError, ConnectionLost, InstrumentError, InstrumentTimeout, ProtocolError

if TYPE_CHECKING:
    from .protocols.bench_config import BenchConfig, InstrumentConfig
    from .safety import CurrentBudget

__all__ = ["Backoff", "InstrumentStatus", "Instrument", "FaultLatched", "log"]

log = logging.getLogger("hystbench.drivers")
T = TypeVar("T")


@dataclass(frozen=True)
class Backoff:
    """Reconnection schedule: initial_s, x factor each attempt, capped at max_s, ``attempts`` tries."""

    initial_s: float = 0.05
    factor: float = 2.0
    max_s: float = 1.0
    attempts: int = 6

    def delays(self) -> Iterator[float]:
        d = self.initial_s
        for _ in range(self.attempts):
            yield d
            d = min(self.max_s, d * self.factor)


@dataclass(frozen=True)
class InstrumentStatus:
    """What an instrument says about itself: healthy or not, which faults, and its telemetry."""

    instrument: str
    ok: bool
    faults: tuple[str, ...] = ()
    values: Mapping[str, Any] = field(default_factory=dict)


class FaultLatched(InstrumentError):
    """An instrument reports a latched fault: the bench acts on it at once, not after a second poll.
    ``faults`` names the latched bits (``OVERCURRENT``, ``INTERLOCK`` ...), so the service can tell
    a trip its own excitation caused from one it cannot control."""

    def __init__(self, message: str, faults: tuple[str, ...] = ()) -> None:
        super().__init__(message)
        self.faults = tuple(faults)


def _is_timeout(err: BaseException) -> bool:
    return isinstance(err, (TimeoutError, socket.timeout)) or type(err).__name__ in (
        "SerialTimeoutException", "ModbusIOException")


class Instrument(abc.ABC):
    """One instrument on the bench.  Use as a context manager: ``with Driver(...) as d: ...``."""

    kind: str = "instrument"
    #: True for the instrument whose disabled state keeps the coil without current whatever the
    #: others do (the current amplifier): the bench opens it first and disables it at once.
    gate: bool = False

    def __init__(self, name: str | None = None, *, timeout_s: float = 1.0,
                 backoff: Backoff | None = None) -> None:
        if not timeout_s > 0:
            raise ConfigError(f"{name or self.kind}: timeout_s must be > 0, got {timeout_s}")
        self.name = name or self.kind
        self.timeout_s = float(timeout_s)
        self.backoff = backoff or Backoff()
        self.reconnects = 0
        self._lock = threading.RLock()
        self._open = False

    # --- life cycle ------------------------------------------------------------------------------
    def open(self) -> "Instrument":
        with self._lock:
            if not self._open:
                log.info("%s: opening", self.name)
                self._open_quietly("open")
        return self

    def _open_quietly(self, what: str) -> None:
        """Run the open hook (which may use the public API); on failure leave nothing half open."""
        self._open = True
        try:
            self._io(what, self._open_hook)
        except BaseException:
            self._open = False
            try:
                self._close_hook()
            except Exception:
                pass
            raise

    def close(self) -> None:
        """Output off (best effort, bounded by the timeout) before the transport goes."""
        with self._lock:
            if not self._open:
                return
            self.safe_off()
            try:
                self._close_hook()
            except Exception as err:  # closing must not raise over the real error
                log.warning("%s: error while closing: %s", self.name, err)
            self._open = False
            log.info("%s: closed", self.name)

    def __enter__(self) -> "Instrument":
        return self.open()

    def __exit__(self, *exc: object) -> None:
        self.close()

    @property
    def is_open(self) -> bool:
        return self._open

    def reconnect(self) -> None:
        """Drop the transport and open it again with back-off; ConnectionLost when attempts run out.
        After a reconnection the instrument's state is unknown, so outputs are switched off."""
        with self._lock:
            try:
                self._close_hook()
            except Exception:
                pass
            self._open = False
            last: BaseException | None = None
            for delay in self.backoff.delays():
                time.sleep(delay)
                try:
                    self._open_quietly("reconnect")
                except InstrumentError as err:
                    last = err
                    log.info("%s: reconnect failed (%s); next try", self.name, err)
                    continue
                self.reconnects += 1
                log.warning("%s: reconnected (%d)", self.name, self.reconnects)
                self.safe_off()
                return
            raise ConnectionLost(f"{self.name}: could not reconnect after {self.backoff.attempts} attempts: "
                                 f"{last}") from last

    # --- public operations -----------------------------------------------------------------------
    def configure(self, **settings: Any) -> None:
        """Apply named settings in the order given; each is checked before anything is sent."""
        self._require_open("configure")
        with self._lock:
            for key, value in settings.items():
                log.debug("%s: configure %s = %r", self.name, key, value)
                self._configure_hook(key, value)

    def status(self) -> InstrumentStatus:
        self._require_open("status")
        with self._lock:
            return self._status_hook()

    def safe_off(self) -> bool:
        """Switch this instrument's output off if it has one; never raises (True if confirmed)."""
        with self._lock:
            try:
                self._safe_off_hook()
                return True
            except Exception as err:
                log.error("%s: could not switch output off: %s", self.name, err)
                return False

    # --- what the bench does with every instrument --------------------------------------------------
    @classmethod
    @abc.abstractmethod
    def from_config(cls, config: InstrumentConfig, bench: BenchConfig, budget: CurrentBudget) -> Self:
        """The driver as the bench file describes it: ``config`` is its table (addresses resolved),
        ``bench`` the file's common keys (see :meth:`_common`), ``budget`` the current budget shared
        by the instruments that can drive current.  Opens nothing."""

    @staticmethod
    def _common(config: InstrumentConfig, bench: BenchConfig) -> dict[str, Any]:
        """Constructor keywords every driver takes from the bench file: its reply deadline (its own
        ``timeout_s`` or the bench's), the reconnection back-off and the common sample rate."""
        return dict(timeout_s=config.timeout_s or bench.timeout_s, backoff=Backoff(**bench.backoff),
                    fs_hz=bench.fs_hz)

    def setup(self, settings: Mapping[str, Any]) -> None:
        """Bring an opened instrument to the state the bench measures in: the bench file's
        ``settings`` (in file order), then whatever else the instrument needs."""
        if settings:
            self.configure(**settings)

    def heartbeat(self) -> None:
        """The bench's periodic poll: proves the link alive (a silent one raises) and feeds any
        watchdog; raises :class:`FaultLatched` when the instrument reports a latched fault."""
        self.status()

    # --- hooks ------------------------------------------------------------------------------------
    @abc.abstractmethod
    def _open_hook(self) -> None: ...

    @abc.abstractmethod
    def _close_hook(self) -> None: ...

    @abc.abstractmethod
    def _configure_hook(self, key: str, value: Any) -> None: ...

    @abc.abstractmethod
    def _status_hook(self) -> InstrumentStatus: ...

    def _safe_off_hook(self) -> None:
        """Instruments that drive the actuator override this."""

    # --- the one place where I/O errors are translated -------------------------------------------
    def _require_open(self, what: str) -> None:
        if not self._open:
            raise ConnectionLost(f"{self.name}: {what} on a closed connection (open() it first)")

    def _io(self, command: str, fn: Callable[[], T]) -> T:
        with self._lock:
            t0 = time.monotonic()
            try:
                result = fn()
            except (InstrumentError, ConfigError):  # ours, already saying what is wrong (a ConfigError
                raise  # is a ValueError too: not an answer the instrument gave)
            except (ValueError, KeyError, IndexError) as err:
                raise ProtocolError(f"{self.name}: unexpected answer to {command!r}: {err}") from err
            except Exception as err:
                if _is_timeout(err):
                    raise InstrumentTimeout(
                        f"{self.name}: no answer to {command!r} within {self.timeout_s:g} s") from err
                raise ConnectionLost(f"{self.name}: connection lost during {command!r}: {err}") from err
            log.debug("%s: %s (%.1f ms)", self.name, command, 1e3 * (time.monotonic() - t0))
            return result
