"""Emulated signal generator: SCPI (the drivers' command table) on TCP and a pseudo-terminal, the
``command_V`` monitor as a length-prefixed frame stream on a second TCP port.

Its settings drive the rig's excitation through ``on_change`` (the bench's rig control); a
setting the rig cannot follow is refused with an error in the queue, as an instrument would.
"""

from __future__ import annotations

import collections
import socket
import threading
from typing import Any, Callable

import numpy as np

from ...blocks import SampleBlock
from ...drivers.protocols import scpi
from ...drivers.protocols.scpi import GENERATOR
from .common import Faults, FrameEmitter, PtyPort, TcpServer, TcpStreamServer, log, queue_scpi_error, scpi_messages

__all__ = ["SignalGeneratorEmulator", "GENERATOR_STREAM_ID"]

GENERATOR_STREAM_ID = 1


class SignalGeneratorEmulator:
    """The signal generator of the module docstring, on real TCP and pseudo-terminal transports, so
    its driver is tested with no hardware."""

    kind = "signal_generator"

    def __init__(self, *, on_change: Callable[[], None] | None = None, serial: bool = True,
                 samples_per_frame: int = 500, identity: str = "HYSTBENCH,SIMGEN-1,0001,1.0") -> None:
        self.faults = Faults()
        self.identity = identity
        self.on_change = on_change or (lambda: None)
        self.state: dict[str, Any] = dict(scpi.RST_STATE)
        self.arb_unit: np.ndarray | None = None
        self.uploads = 0  # arbitrary waveforms received
        self.errors: collections.deque[tuple[int, str]] = collections.deque()
        self.commands_seen: list[bytes] = []
        self._lock = threading.RLock()
        self.scpi = TcpServer(self._serve_tcp, "scpi")
        self.stream = TcpStreamServer("generator-stream", FrameEmitter(GENERATOR_STREAM_ID, samples_per_frame,
                                                                       self.faults))
        self.pty = PtyPort() if serial else None
        self._stop = threading.Event()
        self._pty_thread = None
        if self.pty is not None:
            self._pty_thread = threading.Thread(target=self._serve_pty, name="emu-scpi-pty", daemon=True)
            self._pty_thread.start()

    @property
    def addresses(self) -> dict[str, str]:
        out = {"scpi_tcp": self.scpi.address, "stream_tcp": self.stream.address}
        if self.pty is not None:
            out["serial"] = self.pty.path
        return out

    # --- faults --------------------------------------------------------------------------------------
    def push_error(self, code: int, text: str | None = None) -> None:
        """Put an error in the queue (also how faults 'SCPI errors in the queue' are injected)."""
        with self._lock:
            queue_scpi_error(self.errors, code, text)

    def disconnect(self) -> None:
        """Pull the LAN cable: connections drop, the ports refuse; the serial line goes silent."""
        self.faults.silent = True
        self.scpi.pause()
        self.stream.server.pause()

    def reconnect(self) -> None:
        self.scpi.resume()
        self.stream.server.resume()
        self.faults.silent = False

    # --- the instrument --------------------------------------------------------------------------------
    def handle(self, message: bytes) -> bytes | None:
        """Execute one program message; the reply line (with terminator) or None."""
        with self._lock:
            self.commands_seen.append(message)
            header, is_query, arg = scpi.split_command(message)
            name = next((n for n, c in GENERATOR.items() if scpi.header_matches(c.header, header)), None)
            if name is None:
                self.push_error(-113)
                return None
            ctl = GENERATOR[name]
            if is_query:
                if not ctl.queryable:
                    self.push_error(-113)
                    return None
                if name == "identity":
                    text = self.identity
                elif name == "error":
                    text = scpi.format_error_reply(*(self.errors.popleft() if self.errors else (0, None)))
                else:
                    text = ctl.reply(self.state[name])
                return text.encode() + b"\n"
            if not ctl.settable:
                self.push_error(-113)
                return None
            self._set(name, ctl, arg)
            return None

    def _set(self, name: str, ctl: scpi.Control, arg: bytes) -> None:
        if ctl.kind == "event":
            if arg:
                self.push_error(-108)
            elif name == "reset":
                self.state = dict(scpi.RST_STATE)
                self.arb_unit = None
                self._changed(None)
            else:
                self.errors.clear()
            return
        if ctl.kind == "block":
            try:
                self.arb_unit = scpi.unit_from_dac(scpi.parse_block(arg))
            except ValueError:
                self.push_error(-161)
                return
            self.uploads += 1
            self._changed(None)
            return
        if not arg:
            self.push_error(-109)
            return
        text = arg.decode("ascii", "replace")
        try:
            value = ctl.parse(text)
        except ValueError:
            self.push_error(-104 if ctl.kind == "float" else -224)
            return
        try:
            ctl.check(name, value)
        except ValueError:
            self.push_error(-222)
            return
        if name == "function" and value == "ARB" and self.arb_unit is None:
            self.push_error(-221, "Settings conflict;no arbitrary waveform loaded")
            return
        old = dict(self.state)
        self.state[name] = value
        if abs(self.state["offset_v"]) + self.state["amplitude_vpp"] / 2 > scpi.MAX_OUTPUT_V + 1e-9:
            self.state = old
            self.push_error(-221, "Settings conflict;amplitude + offset exceed output range")
            return
        self._changed(old)

    def _changed(self, old: dict[str, Any] | None) -> None:
        try:
            self.on_change()
        except Exception as err:  # the rig cannot follow (e.g. frequency above Nyquist)
            log.info("generator: rig refused setting: %s", err)
            if old is not None:
                self.state = old
                self.on_change()
            self.push_error(-222, f"Data out of range;{err}")

    def output_volts(self, command_v: np.ndarray) -> np.ndarray:
        return command_v if self.state["output"] else np.zeros_like(command_v)

    def on_block(self, block: SampleBlock) -> None:
        """Stream the output monitor for the rig's newest block."""
        v = self.output_volts(block.channels["command_V"])
        self.stream.send(block.first_index, v[None, :])

    # --- transports ----------------------------------------------------------------------------------
    def _reply(self, write: Callable[[bytes], Any], reply: bytes | None) -> None:
        if reply is None or not self.faults.before_reply():
            return
        write(self.faults.take_bytes("garbage") + reply)
        self.faults.sent_reply()

    def _serve_tcp(self, conn: socket.socket) -> None:
        for msg in scpi_messages(conn, lambda: self.scpi.stopped):
            if not self.faults.is_silent():
                self._reply(conn.sendall, self.handle(msg))

    def _serve_pty(self) -> None:
        reader = scpi.ScpiMessageReader()
        while not self._stop.is_set():
            data = self.pty.read(0.1)
            if not data:
                continue
            for msg in reader.feed(data):
                if not self.faults.is_silent():
                    self._reply(self.pty.write, self.handle(msg))

    def close(self) -> None:
        self._stop.set()
        self.scpi.close()
        self.stream.close()
        if self._pty_thread is not None:
            self._pty_thread.join(timeout=1.0)
        if self.pty is not None:
            self.pty.close()
