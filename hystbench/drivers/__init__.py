"""drivers: one adapter per instrument, each over its real protocol, with its sample stream.

    Instrument (base.py)       open/close/configure/status/safe_off/reconnect; hooks per driver
    ScpiSignalGenerator        SCPI over serial or socket:// (pyserial)       -> command_V stream
    ModbusCurrentAmplifier     Modbus TCP / RTU (pymodbus)                    -> current_A stream
    ChargeAmplifier            Kistler 5070-class ASCII over RS-232           -> force_N stream
    CanFluxIntegrator          CAN / CAN FD (python-can)                      -> flux_Wb stream
    Bench                      the four from a bench file: safety, heartbeat, aligned acquisition

Protocol definitions (command tables, register map, frame codecs, bench-file schema) are in
``drivers.protocols``, which the emulators import.  Names below are imported on first use, so
``import hystbench.drivers`` does not pull in pymodbus or python-can.
"""

from __future__ import annotations

import importlib
from typing import Any

#: Backend table (python-can style): instrument -> (module, class), imported only when needed.
BACKENDS: dict[str, tuple[str, str]] = {
    "signal_generator": ("hystbench.drivers.signal_generator", "ScpiSignalGenerator"),
    "current_amplifier": ("hystbench.drivers.current_amplifier", "ModbusCurrentAmplifier"),
    "charge_amplifier": ("hystbench.drivers.charge_amplifier", "ChargeAmplifier"),
    "flux_integrator": ("hystbench.drivers.flux_integrator", "CanFluxIntegrator"),
}

_PUBLIC = {
    "Instrument": "base", "InstrumentStatus": "base", "Backoff": "base",
    "CurrentBudget": "safety", "SafetyLimitError": "safety",
    "SampleStream": "stream", "StreamStats": "stream", "StreamAligner": "align",
    "ScpiSignalGenerator": "signal_generator", "ScpiError": "signal_generator",
    "ModbusCurrentAmplifier": "current_amplifier", "ModbusError": "current_amplifier",
    "ChargeAmplifier": "charge_amplifier", "ChargeAmpError": "charge_amplifier",
    "CanFluxIntegrator": "flux_integrator", "IntegratorError": "flux_integrator",
    "Bench": "bench", "BenchFault": "bench",
    "BenchConfig": "protocols.bench_config", "load_bench_config": "protocols.bench_config",
}

__all__ = ["BACKENDS", *_PUBLIC]


def __getattr__(name: str) -> Any:
    if name in _PUBLIC:
        return getattr(importlib.import_module(f"{__name__}.{_PUBLIC[name]}"), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
