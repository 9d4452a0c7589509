"""drivers: one adapter per instrument, each over its real protocol, with its sample stream.

    Instrument (base.py)       open/close/configure/status/safe_off/reconnect; hooks per driver
    ScpiSignalGenerator        SCPI over serial or socket:// (pyserial)       -> command_V stream
    ModbusCurrentAmplifier     Modbus TCP / RTU (pymodbus)                    -> current_A stream
    ChargeAmplifier            Kistler 5070-class ASCII over RS-232           -> force_N stream
    CanFluxIntegrator          CAN / CAN FD (python-can)                      -> flux_Wb stream
    digitiser (optional)       SCPI over VISA (pyvisa-py) or NI-DAQmx         -> all four, instead
    Bench                      the four from a bench file: safety, heartbeat, aligned acquisition

Protocol definitions (command tables, register map, frame codecs, bench-file schema) are in
``drivers.protocols``, which the emulators import.  Names below are imported on first use, so
``import hystbench.drivers`` does not pull in pymodbus or python-can.

The bench builds its instruments from :data:`BACKENDS` (python-can's interface table is the
model): a bench-file table name gives the driver class, which builds itself from that table
(``Instrument.from_config``).  Adding an instrument is one row here and one class.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

from ..errors import ConfigError

if TYPE_CHECKING:
    from .base import Instrument

#: Backend table (python-can style): instrument -> (module, class), imported only when needed.
BACKENDS: dict[str, tuple[str, str]] = {
    "signal_generator": ("hystbench.drivers.signal_generator", "ScpiSignalGenerator"),
    "current_amplifier": ("hystbench.drivers.current_amplifier", "ModbusCurrentAmplifier"),
    "charge_amplifier": ("hystbench.drivers.charge_amplifier", "ChargeAmplifier"),
    "flux_integrator": ("hystbench.drivers.flux_integrator", "CanFluxIntegrator"),
}


def instrument_class(name: str) -> type[Instrument]:
    """The driver class of bench-file instrument ``name``, its module imported now (so a bench
    without CAN never imports python-can's driver module before it needs it)."""
    try:
        module, cls = BACKENDS[name]
    except KeyError:
        raise ConfigError(f"no driver for instrument {name!r}; known: {', '.join(BACKENDS)}") from None
    return getattr(importlib.import_module(module), cls)

_PUBLIC = {
    "Instrument": "base", "InstrumentStatus": "base", "Backoff": "base", "FaultLatched": "base",
    "CurrentBudget": "safety", "SafetyLimitError": "safety",
    "SampleStream": "stream", "StreamStats": "stream", "StreamAligner": "align",
    "ScpiSignalGenerator": "signal_generator", "ScpiError": "signal_generator",
    "ModbusCurrentAmplifier": "current_amplifier", "ModbusError": "current_amplifier",
    "ChargeAmplifier": "charge_amplifier", "ChargeAmpError": "charge_amplifier",
    "CanFluxIntegrator": "flux_integrator", "IntegratorError": "flux_integrator",
    "Bench": "bench", "BenchFault": "bench",
    "ScpiDigitiser": "digitiser", "open_digitiser_stream": "digitiser",
    "BenchConfig": "protocols.bench_config", "load_bench_config": "protocols.bench_config",
}

__all__ = ["BACKENDS", "instrument_class", *_PUBLIC]


def __getattr__(name: str) -> Any:
    if name in _PUBLIC:
        return getattr(importlib.import_module(f"{__name__}.{_PUBLIC[name]}"), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
