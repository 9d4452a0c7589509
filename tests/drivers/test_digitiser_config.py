"""The bench file's [digitiser] table: optional (left out: the framed streams), every bad key a
ConfigError naming the file and the key, and the emulator's address filled in for backend = "sim"."""

import pytest

from hystbench.drivers.protocols.bench_config import DEFAULT_BENCH, load_bench_config
from hystbench.errors import ConfigError

TABLE = '''
[digitiser]
backend = "sim"
channels = { current_A = "CHAN1", force_N = "CHAN2", flux_Wb = "CHAN3", command_V = "CHAN4" }
scales = { current_A = 0.2, force_N = 50.0, flux_Wb = 1e-5, command_V = 1.0 }
'''


def load(tmp_path, table):
    p = tmp_path / "bench.toml"
    p.write_text(DEFAULT_BENCH.read_text() + table)
    return load_bench_config(p)


def test_the_table_is_optional_and_checked_when_given(tmp_path):
    assert load_bench_config().digitiser is None
    only_channels = TABLE.split("scales")[0]  # scales left out: 1 SI unit per volt
    assert set(load(tmp_path, only_channels).digitiser.scales.values()) == {1.0}
    d = load(tmp_path, TABLE).digitiser
    assert d.kind == "visa" and d.dialect == "generic" and d.channels["flux_Wb"] == "CHAN3"
    assert d.scales == {"current_A": 0.2, "force_N": 50.0, "flux_Wb": 1e-5, "command_V": 1.0}
    with_long_names = load(tmp_path, TABLE.replace('"CHAN1"', '"channel1"')).digitiser
    assert with_long_names.channels["current_A"] == "channel1"


def test_the_emulators_address_fills_in_a_sim_digitiser(tmp_path):
    cfg = load(tmp_path, TABLE)
    addresses = {n: {"scpi_tcp": "127.0.0.1:1", "stream_tcp": "127.0.0.1:2", "modbus_tcp": "127.0.0.1:3", "unit": 1,
                     "serial": "/dev/null", "stream_serial": "/dev/null", "can_interface": "virtual",
                     "can_channel": "x", "node": 16} for n in cfg.instruments}
    with pytest.raises(ConfigError, match=r"no emulator address for \[digitiser\]"):
        cfg.resolved(addresses)
    got = cfg.resolved({**addresses, "digitiser": {"visa": "TCPIP::127.0.0.1::5025::SOCKET"}})
    assert got.digitiser.url == "TCPIP::127.0.0.1::5025::SOCKET"


@pytest.mark.parametrize("edit, expected", [
    (('backend = "sim"', 'backend = "hardware"\nkind = "daqmx"'),
     r"\[digitiser\] channels.current_A = 'CHAN1': not an NI-DAQmx physical channel"),
    (('"CHAN2"', '"CHAN7"'), r"\[digitiser\] channels.force_N = 'CHAN7': not a channel of dialect 'generic' "
                             r"\(CHAN1, CHAN2, CHAN3, CHAN4\)"),
    (('"CHAN2"', '"CHAN1"'), r"\[digitiser\] channels.force_N = 'CHAN1': already samples current_A"),
    (('"CHAN2"', '"CH2"'), r"channels.force_N = 'CH2': not a channel of dialect 'generic'"),
    (("force_N = 50.0", "force_N = 0.0"), r"\[digitiser\] scales.force_N = 0.0: must be a finite, non-zero number"),
    (("force_N = 50.0", "forse_N = 50.0"), r"\[digitiser.scales\]: unknown key 'forse_N'"),
    (('backend = "sim"', 'backend = "sim"\ndialect = "agilent"'), r"\[digitiser\] dialect: must be one of"),
    (('backend = "sim"', 'backend = "hardware"'), r'\[digitiser\] url: required with backend = "hardware"'),
    (('backend = "sim"', 'backend = "sim"\nkind = "daqmx"'), r'\[digitiser\] kind: the emulated digitiser speaks SCPI'),
    (('backend = "sim"', 'backend = "sim"\nurl_ = ""'), r"\[digitiser\]: unknown key 'url_'"),
    (('backend = "sim"', 'backend = "sim"\nmax_points = 0'), r"\[digitiser\] max_points: must be > 0"),
])
def test_bad_keys_are_refused_naming_file_and_key(tmp_path, edit, expected):
    old, new = edit
    assert old in TABLE
    with pytest.raises(ConfigError, match=expected) as info:
        load(tmp_path, TABLE.replace(old, new, 1))
    assert str(tmp_path / "bench.toml") in str(info.value)


def test_the_tektronix_dialect_names_its_channels_its_way(tmp_path):
    tek = TABLE.replace('backend = "sim"', 'backend = "sim"\ndialect = "tektronix"')
    with pytest.raises(ConfigError, match="'CHAN1': not a channel of dialect 'tektronix' \\(CH1, CH2, CH3, CH4\\)"):
        load(tmp_path, tek)
    assert load(tmp_path, tek.replace('"CHAN', '"CH')).digitiser.channels["command_V"] == "CH4"


def test_a_daqmx_card_takes_its_physical_channels(tmp_path):
    daq = TABLE.replace('backend = "sim"', 'backend = "hardware"\nkind = "daqmx"\nclock_source = "/Dev1/PFI0"')
    d = load(tmp_path, daq.replace('"CHAN', '"Dev1/ai')).digitiser
    assert d.kind == "daqmx" and d.channels["current_A"] == "Dev1/ai1" and d.clock_source == "/Dev1/PFI0"


def test_the_shipped_digitiser_bench_is_bench_toml_plus_the_table():
    from hystbench.config import CONFIG_DIR

    text = (CONFIG_DIR / "bench_digitiser.toml").read_text()
    body = DEFAULT_BENCH.read_text().split("\n[bench]\n", 1)[1]
    assert text.split("\n[bench]\n", 1)[1].startswith(body)  # bench.toml word for word, then [digitiser]
    cfg = load_bench_config(CONFIG_DIR / "bench_digitiser.toml")
    assert cfg.digitiser is not None and cfg.digitiser.is_sim and cfg.digitiser.scales["force_N"] == 50.0


@pytest.mark.parametrize("kind", ["visa", "daqmx"])
def test_each_digitiser_variant_of_bench_hardware_loads_when_uncommented(tmp_path, kind):
    from hystbench.config import CONFIG_DIR

    text = (CONFIG_DIR / "bench_hardware.toml").read_text()
    head, variants = text.split("# --- The digitiser variant", 1)
    blocks = variants.split("# [digitiser]")[1:]
    block = next(b for b in blocks if f'# kind = "{kind}"' in b)
    table = "\n".join(line[2:] if line.startswith("# ") and "=" in line else "" for line in block.splitlines())
    p = tmp_path / "bench.toml"
    p.write_text(head + "\n[digitiser]\n" + table)
    d = load_bench_config(p).digitiser
    assert d.kind == kind and d.backend == "hardware" and set(d.channels) == {"current_A", "force_N", "flux_Wb",
                                                                              "command_V"}


@pytest.mark.parametrize("spelt", ["chan1", "channel1", "Channel1", "CHANnel1"])
def test_a_channel_spelt_any_scpi_way_is_selected_as_that_channel(tmp_path, spelt):
    """Review R1: the file accepts any SCPI spelling of a channel (case-insensitive, short or long),
    so the driver must send that channel: 'chan1' was sent as 'WAV:SOUR 1' (the short form of a
    lower-case word is its digits), which the instrument refuses at open."""
    import dataclasses

    from hystbench.drivers.digitiser import DigitiserFrameSource
    from hystbench.sim_backend.emulators.digitiser import DigitiserEmulator

    cfg = load(tmp_path, TABLE.replace('"CHAN1"', f'"{spelt}"'))
    emu = DigitiserEmulator(cfg.fs_hz, {s: (k, 1.0) for k, s in enumerate(
        ("current_A", "force_N", "flux_Wb", "command_V"), start=1)})
    src = DigitiserFrameSource.from_config(dataclasses.replace(cfg.digitiser, url=emu.addresses["visa"]), cfg)
    try:
        src.open()  # each channel selected with its SYST:ERR? check: a refused one raises here
        assert b"WAV:SOUR CHAN1" in emu.commands_seen
    finally:
        src.close()
        emu.close()


# --- review R1 / H8: errors quote only what the user wrote; the VISA address is checked at load ------
def test_a_signal_left_out_of_channels_is_refused_naming_it_not_given_a_default_channel(tmp_path):
    """A default 'CHANk' would be quoted by a later error (e.g. 'CHAN3': already samples ...) as if
    the user had written it: each of the four signals must be wired explicitly."""
    with pytest.raises(ConfigError, match=r"\[digitiser.channels\]: missing key 'flux_Wb'") as info:
        load(tmp_path, TABLE.replace(', flux_Wb = "CHAN3"', ""))
    assert str(tmp_path / "bench.toml") in str(info.value)
    with pytest.raises(ConfigError, match=r"\[digitiser\]: missing section \[digitiser.channels\]"):
        load(tmp_path, "\n[digitiser]\n")


@pytest.mark.parametrize("url, why", [
    ("socket://192.168.0.30:5025", "unknown interface type"),
    ("TCPIP::192.168.0.30::SOCKET", "port part is mandatory"),
    ("192.168.0.30", "unknown interface type"),
])
def test_a_url_that_is_no_visa_resource_is_refused_at_load_naming_file_and_key(tmp_path, url, why):
    table = TABLE.replace('backend = "sim"', f'backend = "hardware"\nurl = "{url}"')
    with pytest.raises(ConfigError, match=rf"\[digitiser\] url = '{url}': not a VISA resource \(.*{why}") as info:
        load(tmp_path, table)
    assert str(tmp_path / "bench.toml") in str(info.value)
    ok = TABLE.replace('backend = "sim"', 'backend = "hardware"\nurl = "USB0::0x0957::0x1796::MY123::INSTR"')
    assert load(tmp_path, ok).digitiser.url == "USB0::0x0957::0x1796::MY123::INSTR"
