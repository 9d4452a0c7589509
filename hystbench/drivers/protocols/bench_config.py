"""The bench file (``config/bench.toml``): which instrument is where, its protocol options, its
settings, and ``backend = "sim"`` (emulated) or ``"hardware"``.

A pure schema: the drivers' :class:`~hystbench.drivers.bench.Bench` and the emulated bench both read
it.  Every bad table, key or value is a ConfigError naming the file and the key.  Instrument
settings are checked against the instruments' own command tables.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Mapping

from ...config import CONFIG_DIR, read_toml
from ...errors import ConfigError
from . import can_integrator, charge_amp, modbus_map, scpi

__all__ = ["InstrumentConfig", "BenchConfig", "load_bench_config", "INSTRUMENTS", "DEFAULT_BENCH"]

DEFAULT_BENCH = CONFIG_DIR / "bench.toml"
INSTRUMENTS = ("signal_generator", "current_amplifier", "charge_amplifier", "flux_integrator")
_BACKENDS = ("sim", "hardware")

# options per instrument: key -> (type, default)
_OPTIONS: dict[str, dict[str, tuple[type | tuple[type, ...], Any]]] = {
    "signal_generator": {"transport": (str, "tcp"), "url": (str, ""), "stream_url": (str, ""),
                         "baudrate": (int, 115200), "reset_on_open": (bool, True)},
    "current_amplifier": {"transport": (str, "tcp"), "host": (str, ""), "port": (int, 502), "unit": (int, 1),
                          "serial_port": (str, ""), "baudrate": (int, 19200), "stream_url": (str, "")},
    "charge_amplifier": {"url": (str, ""), "stream_url": (str, ""), "baudrate": (int, 115200)},
    "flux_integrator": {"interface": (str, "virtual"), "channel": (str, ""), "node": (int, 0x10),
                        "fd": (bool, True)},
}
_COMMON = {"backend": (str, "sim"), "skew_s": ((int, float), 0.0), "timeout_s": ((int, float), 0.0)}
_TRANSPORTS = {"signal_generator": ("tcp", "serial"), "current_amplifier": ("tcp", "rtu")}
_REQUIRED_HW = {"signal_generator": ("url",), "current_amplifier": (),
                "charge_amplifier": ("url",), "flux_integrator": ("channel",)}

_BENCH = {"max_current_a": ((int, float), None), "fs_hz": ((int, float), 100_000.0),
          "timeout_s": ((int, float), 1.0), "stall_timeout_s": ((int, float), 0.5),
          "heartbeat_s": ((int, float), 0.1), "backoff": (dict, {})}
_BACKOFF = {"initial_s": ((int, float), 0.05), "factor": ((int, float), 2.0), "max_s": ((int, float), 1.0),
            "attempts": (int, 6)}
_SIM = {"rig": (str, "ecore_pm"), "seed": (int, 0), "block_samples": (int, 1000), "pace": (str, "realtime"),
        "effects": (dict, {}), "load_cell_pc_per_n": ((int, float), 3.5), "samples_per_frame": (int, 500)}


def _setting_check(instrument: str, key: str, value: Any) -> None:
    """ValueError if ``value`` is not a legal ``key`` of the instrument's own command table."""
    if instrument == "signal_generator":
        if key not in ("frequency_hz", "amplitude_vpp", "offset_v"):
            raise KeyError(key)
        scpi.GENERATOR[key].check(key, value)
    elif instrument == "current_amplifier":
        reg = {"gain_a_per_v": "gain", "current_limit_a": "current_limit", "watchdog_s": "watchdog"}[key]
        modbus_map.REGISTERS[reg].to_raw(float(value))
    elif instrument == "charge_amplifier":
        if key not in ("sensitivity_pc_per_n", "scale_n_per_v", "time_constant", "lowpass_hz"):
            raise KeyError(key)
        charge_amp.COMMANDS[key].check(key, value)
    else:
        op = can_integrator.OPS[{"gain_v_per_wb": "set_gain", "turns": "set_turns"}[key]]
        if not op.minimum <= float(value) <= op.maximum:
            raise ValueError(f"{key} = {value!r} outside [{op.minimum}, {op.maximum}]")


_SETTING_KEYS = {
    "signal_generator": ("frequency_hz", "amplitude_vpp", "offset_v"),
    "current_amplifier": ("gain_a_per_v", "current_limit_a", "watchdog_s"),
    "charge_amplifier": ("sensitivity_pc_per_n", "scale_n_per_v", "time_constant", "lowpass_hz"),
    "flux_integrator": ("gain_v_per_wb", "turns"),
}


@dataclass(frozen=True)
class InstrumentConfig:
    name: str
    backend: str
    options: dict[str, Any]
    settings: dict[str, Any]  # applied at open, in file order
    skew_s: float = 0.0
    timeout_s: float | None = None

    @property
    def is_sim(self) -> bool:
        return self.backend == "sim"


@dataclass(frozen=True)
class BenchConfig:
    source: str
    max_current_a: float
    fs_hz: float
    timeout_s: float
    stall_timeout_s: float
    heartbeat_s: float
    backoff: dict[str, Any]
    sim: dict[str, Any]
    instruments: dict[str, InstrumentConfig] = field(default_factory=dict)

    @property
    def any_sim(self) -> bool:
        return any(i.is_sim for i in self.instruments.values())

    def resolved(self, addresses: Mapping[str, Mapping[str, Any]]) -> "BenchConfig":
        """A copy in which every ``backend = "sim"`` instrument points at the emulator's addresses
        (as printed by ``hystbench emulate``)."""
        out = {}
        for name, inst in self.instruments.items():
            opts = dict(inst.options)
            if inst.is_sim:
                a = addresses.get(name)
                if a is None:
                    raise ConfigError(f"{self.source}: no emulator address for [{name}]")
                if name == "signal_generator":
                    opts["url"] = "socket://" + a["scpi_tcp"] if opts["transport"] == "tcp" else a["serial"]
                    opts["stream_url"] = "tcp://" + a["stream_tcp"]
                elif name == "current_amplifier":
                    host, _, port = a["modbus_tcp"].rpartition(":")
                    opts.update(host=host, port=int(port), unit=int(a["unit"]), serial_port=a.get("modbus_rtu", ""),
                                stream_url="tcp://" + a["stream_tcp"])
                elif name == "charge_amplifier":
                    opts.update(url=a["serial"], stream_url=a["stream_serial"])
                else:
                    opts.update(interface=a["can_interface"], channel=a["can_channel"], node=int(a["node"]))
            out[name] = replace(inst, options=opts)
        return replace(self, instruments=out)


def _table(data: Any, where: str, schema: Mapping[str, tuple[Any, Any]]) -> dict[str, Any]:
    if not isinstance(data, dict):
        raise ConfigError(f"{where}: must be a table")
    unknown = sorted(set(data) - set(schema))
    if unknown:
        raise ConfigError(f"{where}: unknown key {unknown[0]!r}; known: {', '.join(schema)}")
    out = {}
    for key, (kind, default) in schema.items():
        if key not in data:
            if default is None:
                raise ConfigError(f"{where}: missing key {key!r}")
            out[key] = copy.deepcopy(default)
            continue
        value = data[key]
        if (isinstance(value, bool) and kind is not bool) or not isinstance(value, kind):
            raise ConfigError(f"{where}: key {key!r} must be {getattr(kind, '__name__', kind)}, got {value!r}")
        out[key] = value
    return out


def _instrument(name: str, data: Any, src: str) -> InstrumentConfig:
    where = f"{src} [{name}]"
    if not isinstance(data, dict):
        raise ConfigError(f"{where}: must be a table")
    body = dict(data)
    settings = body.pop("settings", {})
    opts = _table(body, where, {**_COMMON, **_OPTIONS[name]})
    if opts["backend"] not in _BACKENDS:
        raise ConfigError(f"{where}: key 'backend' must be one of {_BACKENDS}, got {opts['backend']!r}")
    if name in _TRANSPORTS and opts["transport"] not in _TRANSPORTS[name]:
        raise ConfigError(f"{where}: key 'transport' must be one of {_TRANSPORTS[name]}, got {opts['transport']!r}")
    if opts["backend"] == "hardware":
        need = list(_REQUIRED_HW[name])
        if name == "current_amplifier":
            need.append("host" if opts["transport"] == "tcp" else "serial_port")
        for key in need:
            if not opts[key]:
                raise ConfigError(f"{where}: key {key!r} is required with backend = \"hardware\"")
    if not isinstance(settings, dict):
        raise ConfigError(f"{where}.settings: must be a table")
    for key, value in settings.items():
        if key not in _SETTING_KEYS[name]:
            raise ConfigError(f"{src} [{name}.settings]: unknown key {key!r}; known: {', '.join(_SETTING_KEYS[name])}")
        try:
            _setting_check(name, key, value)
        except (ValueError, TypeError) as err:
            raise ConfigError(f"{src} [{name}.settings]: key {key!r}: {err}") from err
    backend, skew, timeout = opts.pop("backend"), float(opts.pop("skew_s")), float(opts.pop("timeout_s"))
    return InstrumentConfig(name, backend, opts, dict(settings), skew, timeout or None)


def load_bench_config(path: str | Path | None = None) -> BenchConfig:
    """Read and check a bench file (default: the shipped ``config/bench.toml``)."""
    path = Path(path) if path is not None else DEFAULT_BENCH
    src = str(path)
    data = read_toml(path, "bench file")
    unknown = sorted(set(data) - {"bench", "sim", *INSTRUMENTS})
    if unknown:
        raise ConfigError(f"{src}: unknown table [{unknown[0]}]; known: bench, sim, {', '.join(INSTRUMENTS)}")
    bench = _table(data.get("bench", {}), f"{src} [bench]", _BENCH)
    backoff = _table(bench.pop("backoff"), f"{src} [bench.backoff]", _BACKOFF)
    for key in ("max_current_a", "fs_hz", "timeout_s", "stall_timeout_s", "heartbeat_s"):
        if not bench[key] > 0:
            raise ConfigError(f"{src} [bench]: key {key!r} must be > 0, got {bench[key]!r}")
    sim = _table(data.get("sim", {}), f"{src} [sim]", _SIM)
    if sim["pace"] not in ("realtime", "max"):
        raise ConfigError(f"{src} [sim]: key 'pace' must be 'realtime' or 'max', got {sim['pace']!r}")
    missing = [n for n in INSTRUMENTS if n not in data]
    if missing:
        raise ConfigError(f"{src}: missing table [{missing[0]}]")
    instruments = {n: _instrument(n, data[n], src) for n in INSTRUMENTS}
    return BenchConfig(src, float(bench["max_current_a"]), float(bench["fs_hz"]), float(bench["timeout_s"]),
                       float(bench["stall_timeout_s"]), float(bench["heartbeat_s"]), backoff, sim, instruments)
