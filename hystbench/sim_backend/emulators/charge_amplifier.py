"""Emulated charge amplifier (Kistler 5070 class): the ASCII table of ``protocols.charge_amp`` on one
pseudo-terminal, the output voltage U_F as COBS frames on a second one.

U_F = F * (load-cell sensitivity / set sensitivity) / scale, high-passed by the SHORT/MEDIUM time
constant, low-passed when a filter is set, 0 V in RESET, clipped at +-10 V with OVERLOAD.  The
rig's own instrument model (load cell, frame, the amplifier's fixed 31 kHz low-pass) comes first.
"""

from __future__ import annotations

import threading

import numpy as np
from scipy import signal

from ...blocks import SampleBlock
from ...drivers.protocols import charge_amp as ca
from .common import Faults, FrameEmitter, PtyPort, PtyStreamSink

__all__ = ["ChargeAmplifierEmulator", "CHARGE_AMP_STREAM_ID"]

CHARGE_AMP_STREAM_ID = 3


class _Filter:
    """Stateful SOS filter that starts in steady state for its first input."""

    def __init__(self, sos: np.ndarray) -> None:
        self.sos, self.zi = sos, None

    def __call__(self, x: np.ndarray) -> np.ndarray:
        if self.zi is None:
            self.zi = signal.sosfilt_zi(self.sos) * x[0]
        y, self.zi = signal.sosfilt(self.sos, x, zi=self.zi)
        return y


class ChargeAmplifierEmulator:
    """The charge amplifier of the module docstring, on real pseudo-terminals, so its driver is
    tested byte for byte with no hardware."""

    kind = "charge_amplifier"

    def __init__(self, *, fs_hz: float = 100_000.0, load_cell_pc_per_n: float = 3.5,
                 samples_per_frame: int = 250, identity: str = "5070-SIM,SN0001,1.0") -> None:
        self.faults = Faults()
        self.fs_hz = fs_hz
        self.load_cell_pc_per_n = load_cell_pc_per_n
        self.identity = identity
        self.state = {"mode": "RESET", "sensitivity_pc_per_n": 1.0, "scale_n_per_v": 100.0,
                      "time_constant": "LONG", "lowpass_hz": 0.0}
        self.overload = False  # in the newest block
        self.overload_latched = False
        self._filters: list[_Filter] = []
        self._lock = threading.RLock()
        self.port = PtyPort()
        self.stream = PtyStreamSink(FrameEmitter(CHARGE_AMP_STREAM_ID, samples_per_frame, self.faults))
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._serve, name="emu-charge-amp", daemon=True)
        self._thread.start()

    @property
    def addresses(self) -> dict[str, str]:
        return {"serial": self.port.path, "stream_serial": self.stream.path}

    def disconnect(self) -> None:
        """Cable pulled: silence on both lines."""
        self.faults.silent = True

    def reconnect(self) -> None:
        self.faults.silent = False

    # --- commands ----------------------------------------------------------------------------------
    def handle(self, line: str) -> str:
        with self._lock:
            for name, m in ca.COMMANDS.items():
                if m.query is not None and line == m.query:
                    return self._answer(name, m)
                if m.set is not None:
                    prefix = m.set.split("{}")[0]
                    if ("{}" in m.set and line.startswith(prefix)) or line == m.set:
                        return self._apply(name, m, line[len(prefix):] if "{}" in m.set else None)
            return ca.error_reply(1)

    def _answer(self, name: str, m: ca.Mnemonic) -> str:
        if name == "identity":
            return self.identity
        if name == "status":
            bits = (ca.STATUS["OPERATE"] if self.state["mode"] == "OPERATE" else 0) \
                | (ca.STATUS["OVERLOAD"] if self.overload else 0) \
                | (ca.STATUS["OVERLOAD_LATCHED"] if self.overload_latched else 0)
            return str(bits)
        return m.format(self.state[name])

    def _apply(self, name: str, m: ca.Mnemonic, arg: str | None) -> str:
        if name in ("reset", "operate"):
            self.state["mode"] = "RESET" if name == "reset" else "OPERATE"
            self.overload_latched = False
            return ca.OK
        try:
            value = m.parse(arg or "")
        except ValueError:
            return ca.error_reply(3)
        try:
            m.check(name, value)
        except ValueError:
            return ca.error_reply(2)
        self.state[name] = value
        self._filters = []  # rebuilt for the new settings at the next block
        return ca.OK

    # --- the output ----------------------------------------------------------------------------------
    def _build_filters(self) -> list[_Filter]:
        out = []
        tau = ca.TIME_CONSTANTS_S[self.state["time_constant"]]
        if tau is not None:
            out.append(_Filter(signal.butter(1, 1.0 / (2 * np.pi * tau), "highpass", fs=self.fs_hz, output="sos")))
        lp = float(self.state["lowpass_hz"])
        if lp > 0:
            out.append(_Filter(signal.butter(2, min(lp, 0.45 * self.fs_hz), "lowpass", fs=self.fs_hz, output="sos")))
        return out

    def output_volts(self, force_n: np.ndarray) -> tuple[np.ndarray, bool]:
        """U_F for a block of the rig's force, and whether it clipped."""
        with self._lock:
            if self.state["mode"] != "OPERATE":
                self._filters = []
                return np.zeros_like(force_n), False
            if not self._filters:
                self._filters = self._build_filters()
            u = force_n * (self.load_cell_pc_per_n / self.state["sensitivity_pc_per_n"]) / self.state["scale_n_per_v"]
            for f in self._filters:
                u = f(u)
            clipped = bool(np.any(np.abs(u) > ca.FULL_SCALE_V))
            self.overload = clipped
            self.overload_latched |= clipped
            return np.clip(u, -ca.FULL_SCALE_V, ca.FULL_SCALE_V), clipped

    def on_block(self, block: SampleBlock) -> None:
        u, clipped = self.output_volts(block.channels["force_N"])
        self.stream.send(block.first_index, u[None, :], 4 if clipped else 0)

    # --- transport ------------------------------------------------------------------------------------
    def _serve(self) -> None:
        buf = b""
        while not self._stop.is_set():
            data = self.port.read(0.1)
            if not data:
                continue
            buf += data
            while ca.EOL in buf:
                raw, buf = buf.split(ca.EOL, 1)
                if self.faults.is_silent():
                    continue
                reply = self.handle(raw.decode("ascii", "replace").strip())
                if not self.faults.before_reply():
                    continue
                self.port.write(self.faults.take_bytes("garbage") + reply.encode() + ca.EOL)
                self.faults.sent_reply()
            if len(buf) > 4096:
                buf = b""

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=1.0)
        self.port.close()
        self.stream.close()
