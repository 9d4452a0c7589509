"""The bench file: every bad key is a ConfigError naming the file and the key; instrument settings
are checked against the instruments' own tables; emulator addresses fill in sim instruments."""

import pytest

from hystbench.drivers.protocols.bench_config import DEFAULT_BENCH, INSTRUMENTS, load_bench_config
from hystbench.errors import ConfigError


def write(tmp_path, text):
    p = tmp_path / "bench.toml"
    p.write_text(text)
    return p


def shipped():
    return DEFAULT_BENCH.read_text()


def test_shipped_bench_file_loads_all_sim():
    cfg = load_bench_config()
    assert set(cfg.instruments) == set(INSTRUMENTS) and cfg.any_sim
    assert cfg.max_current_a == 2.0 and cfg.fs_hz == 100_000.0
    assert cfg.instruments["current_amplifier"].settings == {"gain_a_per_v": 0.5, "current_limit_a": 1.8,
                                                             "watchdog_s": 0.5}


@pytest.mark.parametrize("edit, expected", [
    (("[bench]", "[bench]\nmax_curent_a = 3"), "[bench]: unknown key 'max_curent_a'"),
    (("[sim]", "[sim]\nspeed = 2"), "[sim]: unknown key 'speed'"),
    (("[charge_amplifier]", "[charge_amplifier]\nbaud = 9600"), "[charge_amplifier]: unknown key 'baud'"),
    # a scale of -1 N/V is no scale; 0 turns is no sense coil; 50 A/V is beyond the amplifier's
    # 10-10000 mA/V; "fast" is no frequency; a poll period of 0 s would be a busy loop
    (("scale_n_per_v = 50.0", "scale_n_per_v = -1.0"), "[charge_amplifier.settings] scale_n_per_v: must be in ["),
    (("turns = 10", "turns = 0"), "[flux_integrator.settings] turns: must be in [1, "),
    (("gain_a_per_v = 0.5", "gain_a_per_v = 50.0"), "[current_amplifier.settings] gain_a_per_v: must be in [0.01, 10]"),
    (("frequency_hz = 320.0", "frequency_hz = \"fast\""), "[signal_generator.settings] frequency_hz: must be a number"),
    (("lowpass_hz = 0.0", "lowpas_hz = 0.0"), "[charge_amplifier.settings]: unknown key 'lowpas_hz'"),
    (("heartbeat_s = 0.1", "heartbeat_s = 0"), "[bench] heartbeat_s: must be > 0, got 0"),
    (("unit = 1", "unit = \"one\""), "[current_amplifier] unit: must be int"),
    (("attempts = 6", "attempts = 2.5"), "[bench.backoff] attempts: must be int"),
    # an amplifier set to trip above the bench's limit: the drivers refuse to set it when the bench opens
    # (a reload to such a file stopped the running service first, then failed)
    (("max_current_a = 2.0", "max_current_a = 1.0"),
     "[current_amplifier.settings] current_limit_a = 1.8 A exceeds [bench] max_current_a = 1 A"),
    # the emulated rig's switches: named "--effect" (an option nobody gave) when the rig was built
    (("effects = {}", "effects = { zzz = true }"), "[sim] effects: unknown effect 'zzz'"),
    (("effects = {}", "effects = { sensor_noise = { std_force_n = -1.0 } }"), "[sim] effects"),
    # a watchdog the amplifier refuses (exception 3 when the bench opened), or one the heartbeat cannot feed
    (("watchdog_s = 0.5", "watchdog_s = 0.001"),
     "[current_amplifier.settings] watchdog_s = 0.001 s: the amplifier takes 0 (off) or at least 0.05 s"),
    (("watchdog_s = 0.5", "watchdog_s = 0.15"),
     "[current_amplifier.settings] watchdog_s = 0.15 s is shorter than two of [bench] heartbeat_s = 0.1 s"),
    # an emulated rig ticking once a sample: 15 times slower than the clock it emulates, a core busy
    (("block_samples = 20000", "block_samples = 1"),
     "[sim] block_samples = 1: a tick of 10 us at 100000 S/s; the simulated rig makes each tick at once, and below "
     "1 ms a tick's own cost outruns the clock: use at least 100"),
])
def test_bad_keys_name_file_and_key(tmp_path, edit, expected):
    text = shipped().replace(*edit, 1)
    assert text != shipped()
    path = write(tmp_path, text)
    with pytest.raises(ConfigError) as info:
        load_bench_config(path)
    assert str(info.value).startswith(f"{path} ") and expected in str(info.value), str(info.value)


def test_a_watchdog_switched_off_or_two_heartbeats_long_is_taken(tmp_path):
    for watchdog in ("0", "0.2"):
        cfg = load_bench_config(write(tmp_path, shipped().replace("watchdog_s = 0.5", f"watchdog_s = {watchdog}", 1)))
        assert cfg.instruments["current_amplifier"].settings["watchdog_s"] == float(watchdog)


def test_hardware_needs_an_address(tmp_path):
    path = write(tmp_path, shipped().replace('[charge_amplifier]\nbackend = "sim"',
                                             '[charge_amplifier]\nbackend = "hardware"'))
    with pytest.raises(ConfigError, match=r"\[charge_amplifier\] url: required with backend = \"hardware\""):
        load_bench_config(path)


def test_missing_table_unknown_table_and_bad_toml(tmp_path):
    with pytest.raises(ConfigError, match=r"missing section \[flux_integrator\]"):
        load_bench_config(write(tmp_path, shipped().split("[flux_integrator]")[0]))
    with pytest.raises(ConfigError, match=r"unknown section \[oscilloscope\]"):
        load_bench_config(write(tmp_path, shipped() + "\n[oscilloscope]\nx = 1\n"))
    with pytest.raises(ConfigError, match="not valid TOML"):
        load_bench_config(write(tmp_path, "[bench\n"))
    with pytest.raises(ConfigError, match="no such bench file"):
        load_bench_config(tmp_path / "nope.toml")


def test_resolved_points_sim_instruments_at_the_emulators():
    addresses = {
        "signal_generator": {"scpi_tcp": "127.0.0.1:5025", "stream_tcp": "127.0.0.1:5026", "serial": "/dev/pts/7"},
        "current_amplifier": {"modbus_tcp": "127.0.0.1:1502", "unit": 3, "stream_tcp": "127.0.0.1:5027",
                              "modbus_rtu": "/dev/pts/8"},
        "charge_amplifier": {"serial": "/dev/pts/9", "stream_serial": "/dev/pts/10"},
        "flux_integrator": {"can_interface": "virtual", "can_channel": "ch", "node": 16},
    }
    cfg = load_bench_config().resolved(addresses)
    i = cfg.instruments
    assert i["signal_generator"].options["url"] == "socket://127.0.0.1:5025"
    assert i["signal_generator"].options["stream_url"] == "tcp://127.0.0.1:5026"
    assert (i["current_amplifier"].options["host"], i["current_amplifier"].options["port"],
            i["current_amplifier"].options["unit"]) == ("127.0.0.1", 1502, 3)
    assert i["charge_amplifier"].options["stream_url"] == "/dev/pts/10"
    assert i["flux_integrator"].options["channel"] == "ch"


def test_hardware_example_builds_drivers_without_touching_anything():
    from hystbench.config import CONFIG_DIR
    from hystbench.drivers.bench import build_instruments
    from hystbench.drivers.safety import CurrentBudget

    cfg = load_bench_config(CONFIG_DIR / "bench_hardware.toml")
    assert not cfg.any_sim
    drivers = build_instruments(cfg, CurrentBudget(cfg.max_current_a, 0.5))
    assert drivers["current_amplifier"].serial_port == "/dev/ttyUSB0"
    assert drivers["signal_generator"].link.url == "socket://192.168.0.20:5025"
    assert not any(d.is_open for d in drivers.values())


def test_a_tick_of_one_millisecond_is_taken_and_hardware_ignores_the_emulators_tick(tmp_path):
    from hystbench.config import CONFIG_DIR

    cfg = load_bench_config(write(tmp_path, shipped().replace("block_samples = 20000", "block_samples = 100", 1)))
    assert cfg.sim["block_samples"] == 100
    hardware = (CONFIG_DIR / "bench_hardware.toml").read_text()  # no instrument emulated: no rig to tick
    text = hardware.replace("[sim]", "[sim]\nblock_samples = 1", 1) if "[sim]" in hardware else hardware + "\n[sim]\nblock_samples = 1\n"
    got = load_bench_config(write(tmp_path, text))
    assert not got.any_sim and got.sim["block_samples"] == 1
