"""Instrument emulators: each instrument behind its real transport, all driven by one SimulatedRig.

- signal generator: SCPI on a TCP port (SCPI over LAN) and on a pseudo-terminal; command_V stream
  (length-prefixed frames) on a TCP port;
- current amplifier: Modbus TCP and Modbus RTU (pseudo-terminal); current_A stream on a TCP port;
- charge amplifier: ASCII commands on a pseudo-terminal; force stream (COBS frames) on a second one;
- flux integrator: commands and the flux stream (CAN FD) on a python-can bus (virtual by default).

They import the drivers' protocol definitions (``hystbench.drivers.protocols``), never driver logic.
Faults are injected per emulator through its ``faults`` (:class:`Faults`).  The bench that ties
them to one rig is ``hystbench.sim_backend.emulators.bench.EmulatedBench``.
"""

from .common import Faults

__all__ = ["Faults"]
