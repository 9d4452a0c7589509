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
from ...config.schema import NUM, Key
from ...errors import ConfigError
from . import can_integrator, charge_amp, modbus_map, scpi

__all__ = ["InstrumentConfig", "BenchConfig", "load_bench_config", "INSTRUMENTS", "DEFAULT_BENCH", "SCHEMA", "SETTINGS"]

DEFAULT_BENCH = CONFIG_DIR / "bench.toml"
INSTRUMENTS = ("signal_generator", "current_amplifier", "charge_amplifier", "flux_integrator")

# options per instrument: key -> Key (type, default, meaning, unit, legal values)
_OPTIONS: dict[str, dict[str, Key]] = {
    "signal_generator": {
        "transport": Key(str, "tcp", "tcp: SCPI over LAN (url = \"socket://HOST:5025\"); serial: url = a serial "
                         "port", choices=("tcp", "serial")),
        "url": Key(str, "", "the SCPI port (required with backend = \"hardware\")"),
        "stream_url": Key(str, "", "the command_V monitor stream, e.g. \"tcp://HOST:5026\""),
        "baudrate": Key(int, 115200, "serial transport: line speed", "baud", gt=0),
        "reset_on_open": Key(bool, True, "send *RST when the bench opens"),
    },
    "current_amplifier": {
        "transport": Key(str, "tcp", "tcp: Modbus TCP (host, port); rtu: Modbus RTU (serial_port, baudrate)",
                         choices=("tcp", "rtu")),
        "host": Key(str, "", "Modbus TCP host (required with backend = \"hardware\", transport = \"tcp\")"),
        "port": Key(int, 502, "Modbus TCP port", ge=1, le=65535),
        "unit": Key(int, 1, "Modbus unit (slave) id", ge=0, le=255),
        "serial_port": Key(str, "", "Modbus RTU serial port (required with transport = \"rtu\" on hardware)"),
        "baudrate": Key(int, 19200, "Modbus RTU line speed", "baud", gt=0),
        "stream_url": Key(str, "", "the current_A monitor stream, e.g. \"tcp://HOST:5027\""),
    },
    "charge_amplifier": {
        "url": Key(str, "", "the command serial port (required with backend = \"hardware\")"),
        "stream_url": Key(str, "", "the force stream's serial port (COBS frames)"),
        "baudrate": Key(int, 115200, "line speed", "baud", gt=0),
    },
    "flux_integrator": {
        "interface": Key(str, "virtual", "python-can interface; \"socketcan\" with channel = \"can0\" on hardware"),
        "channel": Key(str, "", "CAN channel (required with backend = \"hardware\"; \"\" with sim: a private "
                       "virtual channel)"),
        "node": Key(int, 0x10, "CAN node id (commands on 0x600 + node)", ge=1, le=127),
        "fd": Key(bool, True, "CAN FD (the sample stream needs 64-byte frames)"),
    },
}
_COMMON = {
    "backend": Key(str, "sim", "sim: the emulated instrument; hardware: the address given here",
                   choices=("sim", "hardware")),
    "skew_s": Key(NUM, 0.0, "this instrument's stream lags the common clock by this much", "s"),
    "timeout_s": Key(NUM, 0.0, "reply deadline of this instrument (0: [bench] timeout_s)", "s", ge=0),
}
_REQUIRED_HW = {"signal_generator": ("url",), "current_amplifier": (),
                "charge_amplifier": ("url",), "flux_integrator": ("channel",)}

_BENCH = {
    "max_current_a": Key(NUM, None, "the driver layer refuses any command that could drive more than this",
                         "A", gt=0),
    "fs_hz": Key(NUM, 100_000.0, "the common sample clock of every stream", "Hz", gt=0),
    "timeout_s": Key(NUM, 1.0, "reply deadline of every command", "s", gt=0),
    "stall_timeout_s": Key(NUM, 0.5, "a stream silent this long is reconnected", "s", gt=0),
    "heartbeat_s": Key(NUM, 0.1, "status poll period (feeds the amplifier's watchdog, detects faults)", "s", gt=0),
    "backoff": Key(dict, {}, "the reconnection schedule: [bench.backoff]"),
}
_BACKOFF = {
    "initial_s": Key(NUM, 0.05, "first wait before reconnecting", "s", gt=0),
    "factor": Key(NUM, 2.0, "each wait is this times the previous one ...", ge=1),
    "max_s": Key(NUM, 1.0, "... capped at this", "s", gt=0),
    "attempts": Key(int, 6, "reconnection attempts before the stream gives up", ge=1),
}
_SIM = {
    "rig": Key(str, "ecore_pm", "the simulated rig preset behind the emulated instruments"),
    "seed": Key(int, 0, "random seed of the simulated noise", ge=0),
    "block_samples": Key(int, 1000, "samples per clock tick (10 ms at 100 kS/s)", "samples", gt=0),
    "pace": Key(str, "realtime", "realtime: at the sample clock; max: as fast as computed",
                choices=("realtime", "max")),
    "effects": Key(dict, {}, "switches on top of the rig preset's, e.g. { sensor_noise = false }"),
    "load_cell_pc_per_n": Key(NUM, 3.5, "the emulated load cell's true sensitivity", "pC/N", gt=0),
    "samples_per_frame": Key(int, 500, "TCP/serial stream frames (CAN FD frames hold 10)", "samples", gt=0),
}
#: table name -> its keys, in the file's order (docs/config.md is generated from this).
SCHEMA: dict[str, dict[str, Key]] = {"bench": {k: v for k, v in _BENCH.items() if k != "backoff"},
                                     "bench.backoff": _BACKOFF, "sim": _SIM,
                                     **{n: {**_COMMON, **_OPTIONS[n]} for n in INSTRUMENTS}}


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


def _settings_schema() -> dict[str, dict[str, Key]]:
    """The settings' legal values, read from the instruments' own command tables (which
    ``_setting_check`` enforces), as Keys for docs/config.md (default None: not sent)."""
    out: dict[str, dict[str, Key]] = {}
    for key in _SETTING_KEYS["signal_generator"]:
        c = scpi.GENERATOR[key]
        out.setdefault("signal_generator", {})[key] = Key(NUM, None, c.doc, c.unit, ge=c.minimum, le=c.maximum)
    regs = {"gain_a_per_v": "A/V", "current_limit_a": "A", "watchdog_s": "s"}
    for key, unit in regs.items():
        r = modbus_map.REGISTERS[{"gain_a_per_v": "gain", "current_limit_a": "current_limit",
                                  "watchdog_s": "watchdog"}[key]]
        out.setdefault("current_amplifier", {})[key] = Key(NUM, None, r.doc, unit, ge=r.minimum * r.scale,
                                                           le=r.maximum * r.scale)
    for key in _SETTING_KEYS["charge_amplifier"]:
        m = charge_amp.COMMANDS[key]
        out.setdefault("charge_amplifier", {})[key] = (
            Key(str, None, m.doc, choices=m.choices) if m.kind == "choice"
            else Key(NUM, None, m.doc, m.unit, ge=m.minimum, le=m.maximum))
    for key, (op, unit) in {"gain_v_per_wb": ("set_gain", "V/Wb"), "turns": ("set_turns", "")}.items():
        o = can_integrator.OPS[op]
        out.setdefault("flux_integrator", {})[key] = Key(int if o.value == "u32" else NUM, None, o.doc, unit,
                                                         ge=o.minimum, le=o.maximum)
    return out


#: instrument -> its ``settings`` keys and their ranges (from the instruments' command tables).
SETTINGS: dict[str, dict[str, Key]] = _settings_schema()


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

    @property
    def current_limit_a(self) -> float:
        """The peak coil current a command may ask: ``[bench] max_current_a`` (what the drivers
        enforce) or the amplifier's ``current_limit_a`` setting (beyond it the amplifier trips),
        whichever is smaller."""
        amp = self.instruments.get("current_amplifier")
        limit = amp.settings.get("current_limit_a") if amp is not None else None
        return min(self.max_current_a, float(limit)) if limit is not None else self.max_current_a

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


def _table(data: Any, where: str, schema: Mapping[str, Key]) -> dict[str, Any]:
    if not isinstance(data, dict):
        raise ConfigError(f"{where}: must be a table")
    unknown = sorted(set(data) - set(schema))
    if unknown:
        raise ConfigError(f"{where}: unknown key {unknown[0]!r}; known: {', '.join(schema)}")
    out = {}
    for key, spec in schema.items():
        if key not in data:
            if spec.default is None:
                raise ConfigError(f"{where}: missing key {key!r}")
            out[key] = copy.deepcopy(spec.default)
            continue
        value = data[key]
        bad = spec.problem(value)
        if bad:
            raise ConfigError(f"{where}: key {key!r} {bad}, got {value!r}")
        out[key] = value
    return out


def _instrument(name: str, data: Any, src: str) -> InstrumentConfig:
    where = f"{src} [{name}]"
    if not isinstance(data, dict):
        raise ConfigError(f"{where}: must be a table")
    body = dict(data)
    settings = body.pop("settings", {})
    opts = _table(body, where, {**_COMMON, **_OPTIONS[name]})
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
    sim = _table(data.get("sim", {}), f"{src} [sim]", _SIM)
    missing = [n for n in INSTRUMENTS if n not in data]
    if missing:
        raise ConfigError(f"{src}: missing table [{missing[0]}]")
    instruments = {n: _instrument(n, data[n], src) for n in INSTRUMENTS}
    return BenchConfig(src, float(bench["max_current_a"]), float(bench["fs_hz"]), float(bench["timeout_s"]),
                       float(bench["stall_timeout_s"]), float(bench["heartbeat_s"]), backoff, sim, instruments)
