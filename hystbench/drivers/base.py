"""The common driver interface (python-can style): public methods own locking, timeouts, logging
and error translation once; each instrument overrides only private hooks.

    open() -> _open_hook()             close() -> safe_off() first, then _close_hook()
    configure(**s) -> _configure_hook() status() -> _status_hook()
    safe_off() -> _safe_off_hook()      reconnect() -> close quietly, reopen with Backoff

Every I/O goes through :meth:`Instrument._io`, which turns transport exceptions into the service's
tree (``InstrumentTimeout`` / ``ConnectionLost`` / ``ProtocolError``) naming instrument and command.
"""

from __future__ import annotations

import abc
import logging
import socket
import threading
import time
from dataclasses import dataclass, field
from typing import Any, Callable, Iterator, Mapping, TypeVar

from ..errors import ConfigError, ConnectionLost, InstrumentError, InstrumentTimeout, ProtocolError

__all__ = ["Backoff", "InstrumentStatus", "Instrument", "log"]

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


def _is_timeout(err: BaseException) -> bool:
    return isinstance(err, (TimeoutError, socket.timeout)) or type(err).__name__ in (
        "SerialTimeoutException", "ModbusIOException")


class Instrument(abc.ABC):
    """One instrument on the bench.  Use as a context manager: ``with Driver(...) as d: ...``."""

    kind: str = "instrument"

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
            except InstrumentError:
                raise
            except (ValueError, KeyError, IndexError) as err:
                raise ProtocolError(f"{self.name}: unexpected answer to {command!r}: {err}") from err
            except Exception as err:
                if _is_timeout(err):
                    raise InstrumentTimeout(
                        f"{self.name}: no answer to {command!r} within {self.timeout_s:g} s") from err
                raise ConnectionLost(f"{self.name}: connection lost during {command!r}: {err}") from err
            log.debug("%s: %s (%.1f ms)", self.name, command, 1e3 * (time.monotonic() - t0))
            return result
