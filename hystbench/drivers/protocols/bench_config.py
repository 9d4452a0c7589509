"""The bench file (``config/bench.toml``): which instrument is where, its protocol options, its
settings, and ``backend = "sim"`` (emulated) or ``"hardware"``.

A pure schema: the drivers' :class:`~hystbench.drivers.bench.Bench` and the emulated bench both read
it.  The file is checked by :func:`hystbench.config.schema.check_table` against :data:`SCHEMA`, so
every bad table, key or value is a ConfigError naming the file, the table and the key.  The
ranges of the instruments' settings are read from the instruments' own command tables; what
differs from one instrument to the next (its options, the address it needs on hardware, where
its emulator is) is one row of ``_KINDS``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Callable, Mapping

from ...config import CONFIG_DIR, read_toml
from ...config.effects import validate_effects
from ...config.schema import NUM, OPTIONAL, Key, check_table
from ...errors import ConfigError
from ..safety import DEFAULT_MARGIN, command_limit
from . import can_integrator, charge_amp, modbus_map, scpi, scpi_digitiser
from .framing import MAX_FRAME_SIZE, OVERHEAD

__all__ = ["InstrumentConfig", "BenchConfig", "DigitiserConfig", "load_bench_config", "INSTRUMENTS", "DEFAULT_BENCH",
           "SCHEMA", "SETTINGS"]

DEFAULT_BENCH = CONFIG_DIR / "bench.toml"

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
        "stream_channel": Key(str, "", "CAN channel of the sample stream (\"\": channel, one bus for both; sim: "
                              "a second virtual channel, as python-can's virtual bus filters in Python)"),
    },
}
_COMMON = {
    "backend": Key(str, "sim", "sim: the emulated instrument; hardware: the address given here",
                   choices=("sim", "hardware")),
    "skew_s": Key(NUM, 0.0, "this instrument's stream lags the common clock by this much", "s"),
    "timeout_s": Key(NUM, 0.0, "reply deadline of this instrument (0: [bench] timeout_s)", "s", ge=0),
}

#: The most float32 samples of one channel a stream frame holds (``framing.MAX_FRAME_SIZE``).
MAX_FRAME_SAMPLES = (MAX_FRAME_SIZE - OVERHEAD) // 4

_BENCH = {
    "max_current_a": Key(NUM, None, "the driver layer refuses any command that could drive more than this",
                         "A", gt=0),
    "fs_hz": Key(NUM, 100_000.0, "the common sample clock of every stream", "Hz", gt=0),
    "timeout_s": Key(NUM, 1.0, "reply deadline of every command", "s", gt=0),
    "stall_timeout_s": Key(NUM, 0.5, "a stream silent this long (beyond in_flight_s) is reconnected", "s",
                           gt=0),
    "heartbeat_s": Key(NUM, 0.1, "status poll period (feeds the amplifier's watchdog, which must be two of these "
                        "or longer; detects faults)", "s", gt=0),
    "in_flight_s": Key(NUM, 0.02, "the longest a sample may still be on its way to the drivers once their readers have "
                       "caught up (the instruments' transmit buffers and frames); with emulated instruments at "
                       "least one tick of [sim] block_samples", "s", ge=0),
    "current_margin": Key(NUM, DEFAULT_MARGIN, "share of the trip level (the smaller of max_current_a and the "
                          "amplifier's current_limit_a) no command may use: the measured current's noise, "
                          "distortion and overshoot above the commanded peak", ge=0, lt=0.5),
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
    "block_samples": Key(int, 20_000, "samples per clock tick (200 ms at 100 kS/s), made at once and sent as a "
                         "burst (at most 1e6: a tick is computed and held whole; with emulated instruments at "
                         "least 1 ms of samples, MIN_TICK_S)", "samples", gt=0, le=1_000_000),
    "pace": Key(str, "realtime", "realtime: at the sample clock; max: as fast as computed",
                choices=("realtime", "max")),
    "effects": Key(dict, {}, "switches on top of the rig preset's, e.g. { sensor_noise = false }"),
    "load_cell_pc_per_n": Key(NUM, 3.5, "the emulated load cell's true sensitivity", "pC/N", gt=0),
    "samples_per_frame": Key(int, 500, "TCP/serial stream frames (CAN FD frames hold 17); a frame is at most "
                             "64 KiB", "samples", gt=0, le=MAX_FRAME_SAMPLES),
}


_SIGNALS = ("current_A", "force_N", "flux_Wb", "command_V")
_DIGITISER = {
    "backend": Key(str, "sim", "sim: the emulated digitiser (SCPI on 127.0.0.1); hardware: the address given here",
                   choices=("sim", "hardware")),
    "kind": Key(str, "visa", "visa: SCPI digitiser or oscilloscope (pyvisa-py); daqmx: NI-DAQmx card "
                "(pip install hystbench[nidaqmx])", choices=("visa", "daqmx")),
    "url": Key(str, "", "VISA resource, e.g. \"TCPIP::192.168.0.30::5025::SOCKET\" or \"USB0::...::INSTR\" "
               "(required with kind = \"visa\", backend = \"hardware\")"),
    "dialect": Key(str, "generic", "the SCPI command set: generic (:WAVeform, Keysight style) or a vendor's",
                   choices=tuple(scpi_digitiser.DIALECTS)),
    # each signal required: a default channel would be quoted in errors as if the user had written it
    "channels": Key(dict, None, "the instrument channel sampling each signal (all four required)", table={
        s: Key(str, None, f"the channel of {s} (visa: e.g. \"CHAN{k}\"; daqmx: e.g. \"Dev1/ai{k - 1}\")")
        for k, s in enumerate(_SIGNALS, start=1)}),
    "scales": Key(dict, {}, "SI units per volt at the digitiser's input (1 if left out)", table={
        s: Key(NUM, 1.0, f"{s} per volt") for s in _SIGNALS}),
    "max_points": Key(int, 100_000, "visa: most points one waveform read returns", "points", gt=0),
    "acquisition": Key(str, "stream", "visa: stream (a digitiser acquiring continuously, memory read where the last "
                       "read stopped) or segmented (an oscilloscope: one segment per trigger, armed once per batch; "
                       "the gap between batches is measured by the host clock, an estimate)",
                       choices=("stream", "segmented")),
    "segments": Key(int, 16, "segmented: segments per batch", gt=0),
    "clock_source": Key(str, "", "daqmx: the sample clock terminal (the generator's clock), \"\": the card's own"),
    "trigger_source": Key(str, "", "daqmx: the start trigger terminal, \"\": start at once"),
    "skew_s": Key(NUM, 0.0, "the digitiser samples this much after the common clock", "s"),
    "timeout_s": Key(NUM, 0.0, "reply deadline (0: [bench] timeout_s)", "s", ge=0),
}


def _scpi(key: str) -> Key:
    c = scpi.GENERATOR[key]
    return Key(NUM, OPTIONAL, c.doc, c.unit, ge=c.minimum, le=c.maximum)


def _register(register: str, unit: str) -> Key:
    r = modbus_map.REGISTERS[register]
    return Key(NUM, OPTIONAL, r.doc, unit, ge=r.minimum * r.scale, le=r.maximum * r.scale)


def _mnemonic(key: str) -> Key:
    m = charge_amp.COMMANDS[key]
    if m.kind == "choice":
        return Key(str, OPTIONAL, m.doc, choices=m.choices)
    return Key(NUM, OPTIONAL, m.doc, m.unit, ge=m.minimum, le=m.maximum)


def _op(op: str, unit: str) -> Key:
    o = can_integrator.OPS[op]
    return Key(int if o.value == "u32" else NUM, OPTIONAL, o.doc, unit, ge=o.minimum, le=o.maximum)


#: instrument -> its ``settings`` keys and their ranges, read from the instrument's own command
#: table (left out: not sent; the ones given are sent in file order when the bench opens).
SETTINGS: dict[str, dict[str, Key]] = {
    "signal_generator": {k: _scpi(k) for k in ("frequency_hz", "amplitude_vpp", "offset_v")},
    "current_amplifier": {"gain_a_per_v": _register("gain", "A/V"), "current_limit_a": _register("current_limit", "A"),
                          "watchdog_s": _register("watchdog", "s")},
    "charge_amplifier": {k: _mnemonic(k) for k in ("sensitivity_pc_per_n", "scale_n_per_v", "time_constant",
                                                    "lowpass_hz")},
    "flux_integrator": {"gain_v_per_wb": _op("set_gain", "V/Wb"), "turns": _op("set_turns", "")},
}


def _emulated_generator(opts: Mapping[str, Any], a: Mapping[str, Any]) -> dict[str, Any]:
    return {"url": "socket://" + a["scpi_tcp"] if opts["transport"] == "tcp" else a["serial"],
            "stream_url": "tcp://" + a["stream_tcp"]}


def _emulated_amplifier(opts: Mapping[str, Any], a: Mapping[str, Any]) -> dict[str, Any]:
    host, _, port = a["modbus_tcp"].rpartition(":")
    return {"host": host, "port": int(port), "unit": int(a["unit"]), "serial_port": a.get("modbus_rtu", ""),
            "stream_url": "tcp://" + a["stream_tcp"]}


def _emulated_charge_amp(opts: Mapping[str, Any], a: Mapping[str, Any]) -> dict[str, Any]:
    return {"url": a["serial"], "stream_url": a["stream_serial"]}


def _emulated_integrator(opts: Mapping[str, Any], a: Mapping[str, Any]) -> dict[str, Any]:
    return {"interface": a["can_interface"], "channel": a["can_channel"], "node": int(a["node"]),
            "stream_channel": a.get("can_stream_channel", "")}


@dataclass(frozen=True)
class _Kind:
    """What the bench file says about one instrument: its options, the address options a
    ``hardware`` backend needs (given its options), and where an emulated one is (from the
    addresses ``hystbench emulate`` prints)."""

    options: Mapping[str, Key]
    address: Callable[[Mapping[str, Any]], tuple[str, ...]]
    emulated_at: Callable[[Mapping[str, Any], Mapping[str, Any]], dict[str, Any]]


_KINDS: dict[str, _Kind] = {
    "signal_generator": _Kind(_OPTIONS["signal_generator"], lambda o: ("url",), _emulated_generator),
    "current_amplifier": _Kind(_OPTIONS["current_amplifier"],
                               lambda o: ("host",) if o["transport"] == "tcp" else ("serial_port",),
                               _emulated_amplifier),
    "charge_amplifier": _Kind(_OPTIONS["charge_amplifier"], lambda o: ("url",), _emulated_charge_amp),
    "flux_integrator": _Kind(_OPTIONS["flux_integrator"], lambda o: ("channel",), _emulated_integrator),
}

#: The instruments' tables, in the file's order.
INSTRUMENTS = tuple(_KINDS)

#: The bench file's schema: [bench] (with [bench.backoff]), [sim] and one table per instrument
#: (with its [NAME.settings]), in the file's order; docs/config.md is generated from it.
SCHEMA: dict[str, Key] = {
    "bench": Key(dict, {}, "the bench's limits and timing", table={
        **_BENCH, "backoff": Key(dict, {}, "the reconnection schedule", table=_BACKOFF)}),
    "sim": Key(dict, {}, "the emulated bench (only used by backend = \"sim\" instruments)", table=_SIM),
    **{name: Key(dict, None, f"the {name.replace('_', ' ')}", table={
        **_COMMON, **k.options,
        "settings": Key(dict, {}, "applied in file order when the bench opens", table=SETTINGS[name])})
       for name, k in _KINDS.items()},
    "digitiser": Key(dict, OPTIONAL, "one digitiser samples the four signals instead of the instruments' own "
                     "streams (left out: the framed streams)", table=_DIGITISER),
}


@dataclass(frozen=True)
class DigitiserConfig:
    """The ``[digitiser]`` table, checked: which backend samples which signal on which channel."""

    backend: str
    kind: str
    url: str
    dialect: str
    channels: dict[str, str]
    scales: dict[str, float]
    max_points: int
    acquisition: str
    segments: int
    clock_source: str
    trigger_source: str
    skew_s: float
    timeout_s: float | None

    @property
    def is_sim(self) -> bool:
        return self.backend == "sim"


def _check_visa_resource(url: str, where: str) -> None:
    """A VISA resource string pyvisa can parse (``TCPIP::HOST::PORT::SOCKET``, ``USB0::...::INSTR``,
    ``ASRL/dev/ttyUSB0::INSTR``): refused at load, not at the first open of a running bench."""
    try:
        from pyvisa import rname
    except ImportError:  # a dependency of the package: without it the open says what to install
        return
    try:
        rname.parse_resource_name(url)
    except (rname.InvalidResourceName, ValueError) as err:
        reason = str(err).splitlines()[0] if str(err) else type(err).__name__
        raise ConfigError(f"{where} url = {url!r}: not a VISA resource ({reason}); e.g. "
                          "\"TCPIP::192.168.0.30::5025::SOCKET\" or \"USB0::0x0957::0x1796::MY123::INSTR\"") from None


def _digitiser(t: dict[str, Any], src: str) -> DigitiserConfig:
    where = f"{src} [digitiser]"
    if t["kind"] == "visa":
        d = scpi_digitiser.DIALECTS[t["dialect"]]
        for sig, ch in t["channels"].items():
            if not any(scpi.header_matches(name, ch) for name in d.channel_names):
                raise ConfigError(f"{where} channels.{sig} = {ch!r}: not a channel of dialect {d.name!r} "
                                  f"({', '.join(scpi.short_form(n) for n in d.channel_names)})")
        if t["backend"] == "hardware" and not t["url"]:
            raise ConfigError(f"{where} url: required with backend = \"hardware\" and kind = \"visa\"")
        if t["url"]:
            _check_visa_resource(t["url"], where)
        if t["acquisition"] == "segmented" and not d.segmented:
            raise ConfigError(f"{where} acquisition = \"segmented\": the {d.name} dialect has no segmented "
                              "commands here (generic only)")
    elif t["acquisition"] != "stream":
        raise ConfigError(f"{where} acquisition = {t['acquisition']!r}: NI-DAQmx acquires continuously (\"stream\")")
    elif t["backend"] == "sim":
        raise ConfigError(f"{where} kind: the emulated digitiser speaks SCPI: kind = \"daqmx\" needs "
                          "backend = \"hardware\"")
    else:
        for sig, ch in t["channels"].items():
            if "/" not in ch:
                raise ConfigError(f"{where} channels.{sig} = {ch!r}: not an NI-DAQmx physical channel "
                                  "(e.g. \"Dev1/ai0\")")
    for sig, ch in t["channels"].items():
        if not ch.strip():
            raise ConfigError(f"{where} channels.{sig}: empty")
    seen: dict[str, str] = {}
    for sig, ch in t["channels"].items():
        key = scpi.short_form(ch).upper() if t["kind"] == "visa" else ch
        if key in seen:
            raise ConfigError(f"{where} channels.{sig} = {ch!r}: already samples {seen[key]}")
        seen[key] = sig
    for sig, v in t["scales"].items():
        if v == 0 or v != v or abs(v) == float("inf"):
            raise ConfigError(f"{where} scales.{sig} = {v!r}: must be a finite, non-zero number")
    return DigitiserConfig(t["backend"], t["kind"], t["url"], t["dialect"], dict(t["channels"]), dict(t["scales"]),
                           t["max_points"], t["acquisition"], t["segments"], t["clock_source"], t["trigger_source"],
                           t["skew_s"], t["timeout_s"] or None)


@dataclass(frozen=True)
class InstrumentConfig:
    """One instrument's table of the bench file, checked: its backend (``drivers.BACKENDS``), the
    options its driver is built with and the settings applied at open."""

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
    """A bench file, checked at load: the bench's limits, timeouts and instruments as one typed value
    for the drivers and the bench."""

    source: str
    max_current_a: float
    fs_hz: float
    timeout_s: float
    stall_timeout_s: float
    heartbeat_s: float
    backoff: dict[str, Any]
    sim: dict[str, Any]
    instruments: dict[str, InstrumentConfig] = field(default_factory=dict)
    digitiser: DigitiserConfig | None = None  #: samples the four signals when given
    in_flight_s: float = 0.02  #: ``[bench] in_flight_s`` as written (see :attr:`latency_s`)
    current_margin: float = DEFAULT_MARGIN  #: ``[bench] current_margin`` (see :attr:`current_limit_a`)

    @property
    def latency_s(self) -> float:
        """The longest a sample made before some moment may still arrive after the streams' readers
        caught up with their transports then: ``[bench] in_flight_s``, and with emulated
        instruments at least one clock tick (the emulated rig makes a tick's samples at once, up to
        a tick ahead of real time, and the instruments send them as a burst)."""
        tick = self.sim.get("block_samples", 0) / self.fs_hz if self.any_sim else 0.0
        return max(self.in_flight_s, tick)

    @property
    def any_sim(self) -> bool:
        return any(i.is_sim for i in self.instruments.values()) or (self.digitiser is not None
                                                                    and self.digitiser.is_sim)

    @property
    def current_limit_a(self) -> float:
        """The peak coil current a command may ask: ``[bench] max_current_a`` or the amplifier's
        ``current_limit_a`` setting (beyond it the amplifier trips), whichever is smaller, less
        ``current_margin`` of it (what the drivers' :class:`~hystbench.drivers.safety.CurrentBudget`
        enforces when each command is applied)."""
        amp = self.instruments.get("current_amplifier")
        limit = amp.settings.get("current_limit_a") if amp is not None else None
        return command_limit(self.max_current_a, None if limit is None else float(limit), self.current_margin)

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
                opts.update(_KINDS[name].emulated_at(opts, a))
            out[name] = replace(inst, options=opts)
        dig = self.digitiser
        if dig is not None and dig.is_sim:
            a = addresses.get("digitiser")
            if a is None:
                raise ConfigError(f"{self.source}: no emulator address for [digitiser]")
            dig = replace(dig, url=a["visa"])
        return replace(self, instruments=out, digitiser=dig)


def _instrument(name: str, table: dict[str, Any], raw: Mapping[str, Any], src: str) -> InstrumentConfig:
    """An instrument from its checked table (``raw``: as written, for the settings' order)."""
    opts = dict(table)
    if opts["backend"] == "hardware":
        for key in _KINDS[name].address(opts):
            if not opts[key]:
                raise ConfigError(f"{src} [{name}] {key}: required with backend = \"hardware\"")
    given = opts.pop("settings")
    settings = {k: given[k] for k in raw.get("settings", {})}  # sent in the file's order
    backend, skew, timeout = opts.pop("backend"), opts.pop("skew_s"), opts.pop("timeout_s")
    return InstrumentConfig(name, backend, opts, settings, skew, timeout or None)


def _check_watchdog(watchdog_s: float | None, heartbeat_s: float, src: str) -> None:
    """The amplifier's watchdog against what it takes and how often the bench feeds it: shorter than
    two heartbeats, one late poll switches the output off mid-run (the bench feeds it once a heartbeat)."""
    if not watchdog_s:  # left out, or 0: off
        return
    where = f"{src} [current_amplifier.settings] watchdog_s = {watchdog_s:g} s"
    shortest = modbus_map.WATCHDOG_MIN_MS * modbus_map.REGISTERS["watchdog"].scale
    if watchdog_s < shortest:
        raise ConfigError(f"{where}: the amplifier takes 0 (off) or at least {shortest:g} s")
    if watchdog_s < 2 * heartbeat_s:
        raise ConfigError(f"{where} is shorter than two of [bench] heartbeat_s = {heartbeat_s:g} s: the bench feeds "
                          "the watchdog once a heartbeat, and one late poll would switch the output off; raise it, "
                          "or lower heartbeat_s")


#: The shortest clock tick of the emulated rig: a tick costs it about 0.2 ms of CPU whatever its length
#: (0.16 ms for one sample, 0.20 ms for 100, measured on 2026-11-30), before the instruments send it;
#: ticks of one sample at 100 kS/s ran 15 times slower than the clock they emulate, on a busy core.
MIN_TICK_S = 1e-3


def check_tick(block_samples: int, fs_hz: float, where: str) -> None:
    """A simulated rig's tick (a block it makes at once) long enough for it to keep up with its sample
    clock (MIN_TICK_S); ``where`` names the setting (the file and key, or the option)."""
    if block_samples / fs_hz < MIN_TICK_S:
        raise ConfigError(f"{where}: a tick of {1e6 * block_samples / fs_hz:.3g} us at {fs_hz:g} S/s; the simulated "
                          f"rig makes each tick at once, and below {1e3 * MIN_TICK_S:g} ms a tick's own cost outruns "
                          f"the clock: use at least {math.ceil(MIN_TICK_S * fs_hz)}")


def load_bench_config(path: str | Path | None = None) -> BenchConfig:
    """Read and check a bench file (default: the shipped ``config/bench.toml``)."""
    path = Path(path) if path is not None else DEFAULT_BENCH
    src = str(path)
    data = read_toml(path, "bench file")
    cfg = check_table(data, src, SCHEMA)
    bench = cfg["bench"]
    backoff = bench.pop("backoff")
    instruments = {n: _instrument(n, cfg[n], data[n], src) for n in INSTRUMENTS}
    trip = instruments["current_amplifier"].settings.get("current_limit_a")
    if trip is not None and float(trip) > bench["max_current_a"]:  # the drivers refuse to set it (CurrentBudget)
        raise ConfigError(f"{src} [current_amplifier.settings] current_limit_a = {float(trip):g} A exceeds [bench] "
                          f"max_current_a = {bench['max_current_a']:g} A: the amplifier may not be set to trip above "
                          "the bench's limit; lower it, or raise max_current_a")
    _check_watchdog(instruments["current_amplifier"].settings.get("watchdog_s"), bench["heartbeat_s"], src)
    digitiser = _digitiser(cfg["digitiser"], src) if "digitiser" in cfg else None
    if any(i.is_sim for i in instruments.values()) or (digitiser is not None and digitiser.is_sim):
        check_tick(cfg["sim"]["block_samples"], bench["fs_hz"], f"{src} [sim] block_samples = {cfg['sim']['block_samples']}")
    # the emulated rig's switches, named as this file's (they were named "--effect", an option nobody gave)
    validate_effects(cfg["sim"].get("effects", {}), f"{src} [sim] effects", fs_hz=bench["fs_hz"])
    return BenchConfig(src, bench["max_current_a"], bench["fs_hz"], bench["timeout_s"], bench["stall_timeout_s"],
                       bench["heartbeat_s"], backoff, cfg["sim"], instruments, digitiser, bench["in_flight_s"],
                       bench["current_margin"])
