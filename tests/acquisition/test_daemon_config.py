"""Issue 10 and issue 16 items 5-6: every [source] key is honoured or refused for its kind; a bench
file is a valid --config; the logs go to the state directory unless told otherwise.

The excitation test measures what the emulated bench drives (current amplitude and frequency of
the logged current_A, by FFT) against what the daemon file asked, through the drivers and the
emulated instruments' real protocols."""

from __future__ import annotations

import re
import threading
from pathlib import Path

import numpy as np
import pytest

from hystbench.config import CONFIG_DIR
from hystbench.errors import ConfigError, InstrumentError
from hystbench.formats.mcaplog import iter_blocks
from hystbench.service.daemon_config import load_daemon_config
from hystbench.service.instance import default_log_dir, state_dir
from hystbench.service.service import BenchService


def _cfg(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "daemon.toml"
    path.write_text(f'[daemon]\nlog_dir = "{(tmp_path / "logs").as_posix()}"\n' + text, encoding="utf-8")
    return path


def hardware_bench_file(tmp_path: Path) -> Path:
    """The shipped hardware example with every address made local and unreachable (nothing here
    may reach the LAN): free ports on 127.0.0.1 where nothing listens, serial devices that do not exist."""
    from hystbench.acquisition.zenoh_bus import free_port

    text = (CONFIG_DIR / "bench_hardware.toml").read_text(encoding="utf-8")
    for old in ("192.168.0.20:5025", "192.168.0.20:5026", "192.168.0.21:5027"):
        text = text.replace(old, f"127.0.0.1:{free_port()}")
    text = text.replace("TCPIP::192.168.0.30::", "TCPIP::127.0.0.1::")  # the (commented) digitiser variant
    for dev in ("/dev/ttyUSB0", "/dev/ttyUSB1", "/dev/ttyS0"):
        text = text.replace(dev, (tmp_path / ("absent-" + dev.rsplit("/", 1)[1])).as_posix())
    assert "192.168." not in text
    path = tmp_path / "bench_hardware.toml"
    path.write_text(text, encoding="utf-8")
    return path


@pytest.mark.parametrize("text, match", [
    ('[source]\nkind = "bench"\nfs_hz = 50000.0\n', r'\[source\] fs_hz: not used by kind = "bench": the bench file\'s \[bench\] fs_hz'),
    ('[source]\nblock_samples = 500\n', r"\[source\] block_samples: not used by kind = \"bench\".*\[sim\] block_samples"),
    ('[source]\npace = "max"\n', r"\[source\] pace: not used by kind = \"bench\".*\[sim\] pace"),
    ('[source]\neffects = { bogus = true }\n', r"\[source\] effects.*bogus"),
    ('[source]\nkind = "sim"\neffects = { bogus = true }\n', r"\[source\] effects.*bogus"),
    ('[source]\nkind = "sim"\nbench_file = "x.toml"\n', r'\[source\] bench_file: only kind = "bench" reads a bench file'),
    ('[source]\nkind = "synthetic"\neffects = { sensor_noise = false }\n', r"\[source\] effects: synthetic sines"),
    # a simulated rig read a sample at a time: its cost per block outruns the clock (15x at 100 kS/s)
    ('[source]\nkind = "sim"\nblock_samples = 10\n', r"\[source\] block_samples = 10: a tick of 100 us at 100000 S/s; "
     r"the simulated rig makes each tick at once, and below 1 ms a tick's own cost outruns the clock: use at least 100"),
    ('[source]\ncurrent_pp_a = 50.0\n', r"\[source\].*25 A exceeds the bench's limit of 1\.71 A"),
    ('[source]\nfrequency_hz = 60000.0\n', r"\[source\] frequency_hz = 60000 Hz is outside \[1, 10000\] Hz"),
    ('[sweep]\nfrequencies_hz = [40.0, 90000.0]\n', r"\[sweep\] frequencies_hz\[1\]"),
    ('[sweep]\ncurrent_pp_a = 4.0\n', r"\[sweep\].*2 A exceeds the bench's limit of 1\.71 A"),
    ('[source]\nkind = "synthetic"\n[sweep]\nautostart = true\n', r"\[sweep\] autostart: kind = \"synthetic\""),
])
def test_source_keys_are_honoured_or_refused_naming_why(tmp_path: Path, text: str, match: str) -> None:
    with pytest.raises(ConfigError, match=match):
        load_daemon_config(_cfg(tmp_path, text))


def test_hardware_bench_refuses_the_emulated_rigs_keys(tmp_path: Path) -> None:
    bench = hardware_bench_file(tmp_path)
    for extra, key in (("effects = { sensor_noise = false }\n", "effects"), ("seed = 3\n", "seed")):
        with pytest.raises(ConfigError, match=rf"\[source\] {key}: applies to the emulated rig.*hardware instruments"):
            load_daemon_config(_cfg(tmp_path, f'[source]\nkind = "bench"\nbench_file = "{bench.as_posix()}"\n{extra}'))
    cfg = load_daemon_config(_cfg(tmp_path, f'[source]\nbench_file = "{bench.as_posix()}"\nrig = "ecore"\n'))
    assert cfg["source"]["rig"] == "ecore"  # with hardware the rig only names the recordings


def test_a_bench_file_too_slow_to_play_any_frequency_is_blamed_not_the_frequency(tmp_path: Path) -> None:
    """A bench file's fs_hz = 1e-300 was refused as "[source] frequency_hz = 320 Hz is outside [1, 1e-301]
    Hz"; it is the bench file's rate that no frequency fits (10 samples per period of 1 Hz)."""
    bench = tmp_path / "slow.toml"
    bench.write_text((CONFIG_DIR / "bench.toml").read_text(encoding="utf-8").replace("fs_hz = 100000.0", "fs_hz = 1e-300"),
                     encoding="utf-8")
    with pytest.raises(ConfigError, match=rf"^{re.escape(str(bench))} \[bench\] fs_hz: 1e-300 Hz is too slow to play any frequency: 10 "
                                          r"samples per period of the lowest, 1 Hz, need at least 10 Hz$"):
        load_daemon_config(_cfg(tmp_path, f'[source]\nkind = "bench"\nbench_file = "{bench.as_posix()}"\n'))


def test_an_emulated_bench_refuses_a_rig_without_the_channels_it_streams(tmp_path: Path) -> None:
    """kind = "bench" with the toroid (no force for the charge amplifier) was accepted, then gave no
    sample while health said running and every command was answered ok; a voice coil has no flux."""
    for rig, what in (("toroid", "force"), ("voicecoil_ferrite", "flux")):
        with pytest.raises(ConfigError, match=rf"\[source\] rig: '{rig}' has no {what} channel for the emulated bench's .*; run it as kind = \"sim\""):
            load_daemon_config(_cfg(tmp_path, f'[source]\nkind = "bench"\nrig = "{rig}"\n'))
    assert load_daemon_config(_cfg(tmp_path, '[source]\nkind = "bench"\nrig = "ecore"\n'))["source"]["rig"] == "ecore"


def test_an_emulated_bench_reports_the_bench_files_rig() -> None:
    assert load_daemon_config(None)["source"]["rig"] == "ecore_pm"  # the shipped bench.toml's [sim] rig


def test_bench_kind_drives_the_configured_excitation(tmp_path: Path) -> None:
    """Issue 10: frequency_hz = 160, current_pp_a = 1.0 through the emulated instruments: the logged
    coil current must be a 160 Hz sine of 1.0 A peak to peak (not the bench file's 320 Hz, 1.4 A-pp)."""
    cfg = load_daemon_config(_cfg(tmp_path, '[source]\nkind = "bench"\nfrequency_hz = 160.0\ncurrent_pp_a = 1.0\n'
                                            'effects = { sensor_noise = false }\n[zenoh]\nenabled = false\n'
                                            '[recording]\nidle_raw = "off"\n'))
    svc = BenchService(cfg).start()
    try:
        assert svc.source.emu.rig.effects.get("sensor_noise") is None  # the daemon's effects reached the rig
        done = threading.Event()
        svc.pipeline.listeners.append(lambda t, o: done.set() if t == "/estimate" and not o["error"] else None)
        svc.command("output", {"on": True})
        assert done.wait(30.0)
    finally:
        paths = svc.stop()
    on = [b for p in paths for b in iter_blocks(p) if b.meta.get("output_on") and not b.meta.get("settling")]
    assert on and all(b.meta["frequency_hz"] == 160.0 for b in on)
    x = np.concatenate([b.channels["current_A"] for b in on]).astype(float)
    x = x[: len(x) // 1000 * 1000]
    spectrum = np.abs(np.fft.rfft(x - x.mean()))
    f_peak = np.argmax(spectrum) * on[0].fs_hz / len(x)
    assert abs(f_peak - 160.0) <= on[0].fs_hz / len(x)  # within one bin
    pp = np.percentile(x, 99.9) - np.percentile(x, 0.1)
    assert pp == pytest.approx(1.0, rel=0.05)


def test_a_bench_file_is_a_valid_daemon_config(tmp_path: Path) -> None:
    """Issue 16 item 5: `daemon --config bench_hardware.toml` as the file says: accepted, it runs the
    daemon's defaults with that bench; it fails only when the first instrument is opened, naming
    it and its address (a serial device that is not there: at once)."""
    bench = hardware_bench_file(tmp_path)
    cfg = load_daemon_config(bench)
    assert (cfg["source"]["kind"], cfg["source"]["bench_file"]) == ("bench", str(bench))
    assert cfg["daemon"]["bench"] == "bench1" and cfg.source == str(bench)
    with pytest.raises(InstrumentError, match=r"current_amplifier.*absent-ttyUSB0"):
        BenchService(cfg)
    mixed = tmp_path / "mixed.toml"
    mixed.write_text(bench.read_text() + '\n[daemon]\nbench = "x"\n', encoding="utf-8")
    with pytest.raises(ConfigError, match=r"bench file's \[bench\] table and the daemon's \[daemon\]"):
        load_daemon_config(mixed)


def test_state_directory_systemd_then_xdg_then_home(monkeypatch, tmp_path: Path) -> None:
    monkeypatch.setenv("STATE_DIRECTORY", f"{tmp_path}/sd:/elsewhere")
    monkeypatch.setenv("XDG_STATE_HOME", str(tmp_path / "xdg"))
    assert state_dir()[0] == tmp_path / "sd" and default_log_dir()[0] == tmp_path / "sd" / "logs"
    monkeypatch.delenv("STATE_DIRECTORY")
    assert state_dir()[0] == tmp_path / "xdg" / "hystbench"
    assert load_daemon_config(None)["daemon"]["log_dir"] == str(tmp_path / "xdg" / "hystbench" / "logs")
    monkeypatch.delenv("XDG_STATE_HOME")
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    assert state_dir()[0] == tmp_path / "home" / ".local" / "state" / "hystbench"
    cfg = _cfg(tmp_path, "")  # an explicit log_dir wins
    assert load_daemon_config(cfg)["daemon"]["log_dir"] == str(tmp_path / "logs")


def test_a_bench_file_as_config_is_checked_as_a_bench_file(tmp_path: Path) -> None:
    """The daemon hands a bench file to the bench file's own schema: a table no bench file has is
    refused naming the file and the table, a bad key in it naming the table and the key."""
    bench = hardware_bench_file(tmp_path)
    extra = tmp_path / "extra.toml"
    extra.write_text(bench.read_text(encoding="utf-8") + '\n[oscilloscope]\nurl = "x"\n', encoding="utf-8")
    with pytest.raises(ConfigError, match=rf"^{extra}: unknown section \[oscilloscope\]; known: bench, sim, "):
        load_daemon_config(extra)
    bad = tmp_path / "bad.toml"
    bad.write_text(bench.read_text(encoding="utf-8").replace("heartbeat_s = 0.1", "heartbeat_s = -0.1"),
                   encoding="utf-8")
    with pytest.raises(ConfigError, match=rf"^{bad} \[bench\] heartbeat_s: must be > 0, got -0.1"):
        load_daemon_config(bad)


def test_a_daemon_file_that_is_not_utf8_is_refused_naming_it(tmp_path: Path) -> None:
    path = tmp_path / "latin.toml"
    path.write_bytes(b'[daemon]\nbench = "b\xe9nch"\n')
    with pytest.raises(ConfigError, match=rf"^{path}: cannot read the file"):
        load_daemon_config(path)
    with pytest.raises(ConfigError, match=rf"^{tmp_path / 'absent.toml'}: no such file"):
        load_daemon_config(tmp_path / "absent.toml")
