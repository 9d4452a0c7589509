"""Byte links with deadlines for the line-oriented instruments (SCPI, the charge amplifier's ASCII).

``serial.serial_for_url`` opens a serial device, ``socket://host:port`` (SCPI over LAN) or a pty
path alike, so one class serves every serial-style instrument.  Every read has a deadline; a link
that is gone raises ``OSError``/``SerialException``, which :meth:`Instrument._io` reports as
``ConnectionLost``.
"""

from __future__ import annotations

import socket

import serial

from ..deadline import Deadline

__all__ = ["SerialLink"]


class SerialLink:
    """One line-oriented link (serial, ``socket://``, a pty) with a deadline on every read (module
    docstring)."""

    def __init__(self, url: str, *, baudrate: int = 115200, timeout_s: float = 1.0, eol: bytes = b"\n",
                 max_line: int = 1 << 16) -> None:
        self.url = url
        self.baudrate = baudrate
        self.timeout_s = timeout_s
        self.eol = eol
        self.max_line = max_line
        self._port: serial.SerialBase | None = None
        self._buf = bytearray()

    def open(self) -> None:
        self.close()
        self._port = serial.serial_for_url(self.url, baudrate=self.baudrate, timeout=self.timeout_s,
                                           write_timeout=self.timeout_s)
        sock = getattr(self._port, "_socket", None)  # socket:// - no Nagle delay between small commands
        if sock is not None:
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self._buf.clear()
        self.reset_input()

    def close(self) -> None:
        port, self._port = self._port, None
        if port is None:
            return
        sock = getattr(port, "_socket", None)
        if sock is not None:  # pyserial's socket:// close() sleeps 0.3 s; reconnection backs off here
            try:
                sock.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass
            sock.close()
            port._socket = None
            port.is_open = False
        else:
            port.close()

    @property
    def is_open(self) -> bool:
        return self._port is not None

    def _require(self) -> serial.SerialBase:
        if self._port is None:
            raise serial.SerialException(f"{self.url} is not open")
        return self._port

    @property
    def waiting(self) -> int:
        """Bytes received and not read yet (e.g. a late reply the next command will flush)."""
        return len(self._buf) + self._require().in_waiting

    def reset_input(self) -> None:
        """Forget bytes that arrived before a command (stale replies, line noise)."""
        port = self._require()
        self._buf.clear()
        port.timeout = 0
        while port.read(4096):
            pass
        port.timeout = self.timeout_s

    def write(self, data: bytes) -> None:
        self._require().write(data)

    def read_line(self, timeout_s: float | None = None) -> bytes:
        """One line without its terminator; TimeoutError if none completes in time."""
        port = self._require()
        deadline = Deadline(self.timeout_s if timeout_s is None else timeout_s)
        while True:
            end = self._buf.find(self.eol)
            if end >= 0:
                line = bytes(self._buf[:end])
                del self._buf[:end + len(self.eol)]
                return line
            if len(self._buf) > self.max_line:
                self._buf.clear()
                raise ValueError(f"{self.url}: more than {self.max_line} bytes without a line end")
            if deadline.expired:
                raise TimeoutError(f"{self.url}: no complete line within the timeout")
            port.timeout = deadline.left(0.05)
            chunk = port.read(max(1, port.in_waiting))
            if chunk:
                self._buf += chunk
