"""Emulated current amplifier: Modbus TCP (127.0.0.1) and Modbus RTU (pseudo-terminal) on the
drivers' register map, and the ``current_A`` monitor as a length-prefixed frame stream.

Its enable, gain and limit gate the rig's current (through ``on_change``): the output is on only
when enabled and no fault is latched; |i| above the limit latches OVERCURRENT and disables it; no
request for longer than the watchdog latches WATCHDOG and disables it.  The watchdog counts on the
emulated bench's sample clock (the emulator's only time): on a machine too busy to keep real time
the clock slows down with everything else, so a host that keeps polling is never cut off.
"""

from __future__ import annotations

import socket
import threading
from typing import Callable

import numpy as np

from ...blocks import SampleBlock
from ...drivers.protocols import modbus_map as mb
from .common import Faults, FrameEmitter, PtyPort, TcpServer, TcpStreamServer, log

__all__ = ["CurrentAmplifierEmulator", "AMPLIFIER_STREAM_ID"]

AMPLIFIER_STREAM_ID = 2
R = mb.REGISTERS


class CurrentAmplifierEmulator:
    """The current amplifier of the module docstring, on real Modbus transports, so its driver and
    the bench's safety logic are tested with no hardware."""

    kind = "current_amplifier"

    def __init__(self, *, unit: int = 1, gain_a_per_v: float = 0.5, current_limit_a: float = 2.0,
                 on_change: Callable[[], None] | None = None, serial: bool = True,
                 samples_per_frame: int = 500, firmware: int = 0x0102) -> None:
        self.faults = Faults()
        self.unit = unit
        self.on_change = on_change or (lambda: None)
        self.regs = [0] * mb.N_REGISTERS
        self.regs[R["model_id"].address] = mb.MODEL_ID
        self.regs[R["firmware"].address] = firmware
        self.regs[R["gain"].address] = R["gain"].to_raw(gain_a_per_v)
        self.regs[R["current_limit"].address] = R["current_limit"].to_raw(current_limit_a)
        self.regs[R["temperature"].address] = 2500
        self.enabled = False
        self.latched = 0
        self.requests = 0
        self._clock_end: int | None = None  # one past the newest sample of the clock
        self._last_request_index: int | None = None  # where the clock was at the last request
        self._lock = threading.RLock()
        self.modbus_tcp = TcpServer(self._serve_tcp, "modbus")
        self.stream = TcpStreamServer("amplifier-stream", FrameEmitter(AMPLIFIER_STREAM_ID, samples_per_frame,
                                                                       self.faults))
        self.pty = PtyPort() if serial else None
        self._stop = threading.Event()
        self._rtu_thread = None
        if self.pty is not None:
            self._rtu_thread = threading.Thread(target=self._serve_rtu, name="emu-modbus-rtu", daemon=True)
            self._rtu_thread.start()

    @property
    def addresses(self) -> dict[str, str | int]:
        out: dict[str, str | int] = {"modbus_tcp": self.modbus_tcp.address, "unit": self.unit,
                                     "stream_tcp": self.stream.address}
        if self.pty is not None:
            out["modbus_rtu"] = self.pty.path
        return out

    # --- state the rig follows ---------------------------------------------------------------------
    @property
    def gain_a_per_v(self) -> float:
        return R["gain"].to_si(self.regs[R["gain"].address])

    @property
    def current_limit_a(self) -> float:
        return R["current_limit"].to_si(self.regs[R["current_limit"].address])

    @property
    def output_on(self) -> bool:
        return self.enabled and not self.latched

    def trip(self, fault: str) -> None:
        """Latch a fault (OVERCURRENT, OVERTEMP, WATCHDOG, INTERLOCK, SUPPLY): output off."""
        with self._lock:
            self.latched |= mb.FAULTS[fault]
            was, self.enabled = self.enabled, False
        if was:
            log.warning("amplifier: %s fault, output disabled", fault)
        self.on_change()

    def disconnect(self) -> None:
        """Pull the LAN cable: connections drop, the ports refuse; the serial line goes silent."""
        self.faults.silent = True
        self.modbus_tcp.pause()
        self.stream.server.pause()

    def reconnect(self) -> None:
        self.modbus_tcp.resume()
        self.stream.server.resume()
        self.faults.silent = False

    # --- registers -----------------------------------------------------------------------------------
    def _status_word(self) -> int:
        s = mb.STATUS["ENABLED"] if self.output_on else 0
        s |= mb.STATUS["FAULT"] if self.latched else 0
        s |= mb.STATUS["WATCHDOG_ARMED"] if self.regs[R["watchdog"].address] else 0
        return s

    def _read(self, address: int, count: int) -> list[int]:
        if address + count > mb.N_REGISTERS:
            raise mb.ModbusException(2)
        self.regs[R["status"].address] = self._status_word()
        self.regs[R["faults"].address] = self.latched
        self.regs[R["control"].address] = mb.CONTROL["ENABLE"] if self.enabled else 0
        return self.regs[address:address + count]

    def _write(self, address: int, values: list[int]) -> None:
        if address + len(values) > mb.N_REGISTERS:
            raise mb.ModbusException(2)
        regs = [r for r in R.values() if address <= r.address < address + len(values)]
        if any(r.access != "RW" for r in regs):
            raise mb.ModbusException(2)
        for r, v in zip(regs, values):
            if not r.minimum <= (v - 0x10000 if r.signed and v >= 0x8000 else v) <= r.maximum:
                raise mb.ModbusException(3)
            if r.name == "watchdog" and 0 < v < mb.WATCHDOG_MIN_MS:
                raise mb.ModbusException(3)
        for r, v in zip(regs, values):
            if r.name == "control":
                if v & mb.CONTROL["CLEAR_FAULTS"]:
                    self.latched = 0
                self.enabled = bool(v & mb.CONTROL["ENABLE"])
            else:
                self.regs[r.address] = v
        self.on_change()

    def handle_pdu(self, pdu: bytes) -> bytes:
        with self._lock:
            self.requests += 1
            self._last_request_index = self._clock_end
            if self.faults.modbus_exception and self.faults.take("modbus_exception_count"):
                return bytes(((pdu[0] if pdu else 0) | 0x80, self.faults.modbus_exception))
            return mb.server_response(pdu, self._read, self._write)

    # --- the monitor, the watchdog and the current limit, once per rig block -----------------------
    def on_block(self, block: SampleBlock) -> None:
        i = block.channels["current_A"]
        with self._lock:
            self._clock_end = block.end_index
            if self._last_request_index is None:
                self._last_request_index = block.first_index
            wd = R["watchdog"].to_si(self.regs[R["watchdog"].address])
            idle = (block.end_index - self._last_request_index) / block.fs_hz
            if i.size:
                self.regs[R["current"].address] = int(np.clip(round(i[-1] * 1e3), -32768, 32767)) & 0xFFFF
                rms = float(np.sqrt(np.mean(i * i)))
                self.regs[R["current_rms"].address] = min(0xFFFF, int(round(rms * 1e3)))
                self.regs[R["temperature"].address] = int(round(100 * (25.0 + 8.0 * rms * rms)))
        if wd and self.enabled and idle > wd:
            self.trip("WATCHDOG")
        elif self.output_on and i.size and float(np.max(np.abs(i))) > self.current_limit_a:
            self.trip("OVERCURRENT")
        self.stream.send(block.first_index, i[None, :])  # the instruments flag their own overloads

    # --- transports ----------------------------------------------------------------------------------
    def _serve_tcp(self, conn: socket.socket) -> None:
        conn.settimeout(0.2)
        buf = b""
        while not self.modbus_tcp.stopped:
            try:
                data = conn.recv(4096)
            except socket.timeout:
                continue
            if not data:
                return
            buf += data
            while len(buf) >= mb.MBAP.size:
                tid, proto, length, unit = mb.MBAP.unpack_from(buf)
                if proto != 0 or not 2 <= length <= 254:
                    return  # not Modbus: a real server drops the connection
                if len(buf) < 6 + length:
                    break
                pdu, buf = buf[mb.MBAP.size:6 + length], buf[6 + length:]
                if unit != self.unit:
                    continue
                reply = self.handle_pdu(pdu)
                if self.faults.before_reply():
                    conn.sendall(self.faults.take_bytes("garbage") + mb.mbap(tid, unit, reply))
                    self.faults.sent_reply()

    def _serve_rtu(self) -> None:
        buf = b""
        while not self._stop.is_set():
            data = self.pty.read(0.05)
            if not data:
                buf = b""  # silence between frames ends any partial frame (t3.5)
                continue
            buf += data
            while (n := mb.rtu_request_length(buf)) is not None and len(buf) >= n:
                frame, buf = buf[:n], buf[n:]
                if mb.crc16(frame[:-2]) != int.from_bytes(frame[-2:], "little"):
                    buf = b""  # a slave ignores a bad frame and waits for the line to go quiet
                    break
                if frame[0] != self.unit:
                    continue
                reply = bytes((self.unit,)) + self.handle_pdu(frame[1:-2])
                if self.faults.before_reply():
                    self.pty.write(self.faults.take_bytes("garbage") + reply +
                                   mb.crc16(reply).to_bytes(2, "little"))
                    self.faults.sent_reply()

    def close(self) -> None:
        self._stop.set()
        self.modbus_tcp.close()
        self.stream.close()
        if self._rtu_thread is not None:
            self._rtu_thread.join(timeout=1.0)
        if self.pty is not None:
            self.pty.close()
