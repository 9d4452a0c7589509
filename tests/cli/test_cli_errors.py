"""Issue 11: nothing a user can type ends in a traceback or an exit status other than 0 or 2.

Every case below was found by feeding each command edge values (0, negative, huge, nan, inf, empty,
wrong file types); before the fix each ended in a traceback (OverflowError, IndexError, zenoh's
ZError, numpy's "cannot convert float NaN to integer"), in main's last-resort line that names no
option or file ("negative timeout", "'utf-8' codec can't decode ..."), in a wait without end, or in
exit 0 after writing into the current folder.  Now each is refused with exit 2 and one line that
names the option (argparse's "argument --X") or the file, and leaves nothing behind.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from hystbench.cli.main import main
from hystbench.config import CONFIG_DIR

pytestmark = pytest.mark.slow(25)  # ~25 s: handed to a worker before lighter files (tests/conftest.py)

GARBAGE = bytes(range(256)) * 4  # not UTF-8: a binary file given where text is expected
DEAD = "tcp/127.0.0.1:9"  # nobody listens on the discard port: a request there finds no daemon


@pytest.fixture(scope="module")
def model_file(model_file_of) -> Path:
    """A real model file (the simulated ecore_pm's, fitted once per run)."""
    return model_file_of("ecore_pm")


SIM = ["simulate", "--rig", "ecore", "--freq", "320", "--ipp", "1", "--duration", "0.01", "--out", "TMP/out/s"]
COMP = ["compensate", "--direct", "--measure", "0.05", "--iterations", "1", "--json"]
FORCE = ["--force", "offset=170,amp=40,freq=320"]

#: (id, command line, words the one error line must hold).  TMP/ is the test's folder; GARBAGE,
#: EMPTY_CSV and MODEL are files made there.
CASES = [
    # numbers the simulated rig cannot take: NaN inside the iron model, an overflowing sample index
    ("simulate --ipp 1e308", SIM[:6] + ["1e308"] + SIM[7:], ["argument --ipp", "'1e308'", "20000"]),
    ("simulate-sweep --ipp 1,1e308", ["simulate-sweep", "--ipp", "1,1e308", "--out", "TMP/out/sw"],
     ["argument --ipp", "'1e308'"]),
    ("record --ipp 1e308", ["record", "--source", "sim", "--ipp", "1e308", "--out", "TMP/out/r.mcap"],
     ["argument --ipp", "'1e308'"]),
    ("simulate --freq 1e-300", SIM[:4] + ["1e-300"] + SIM[5:], ["1e-300 Hz", "raise the frequency"]),
    ("simulate-sweep --freqs 1e-300", ["simulate-sweep", "--freqs", "1e-300", "--duration", "0.01", "--out",
                                       "TMP/out/sw"], ["1e-300 Hz", "raise the frequency"]),
    ("record --fs 100 (load cell above fs/2)", ["record", "--source", "sim", "--rig", "ecore", "--fs", "100",
                                                "--pace", "max", "--seconds", "0.1", "--out", "TMP/out/r.mcap"],
     ["excitation frequency 320", "fs/2 = 50"]),
    ("record --block 1e9", ["record", "--source", "sim", "--block", "1000000000", "--out", "TMP/out/r.mcap"],
     ["argument --block", "'1000000000'"]),
    ("record --block 1 (a busy core)", ["record", "--source", "sim", "--block", "1", "--out", "TMP/out/r.mcap"],
     ["--block 1 (--fs 100000): a tick of 10 us", "below 1 ms", "use at least 100"]),
    ("record --seconds 1e308", ["record", "--source", "synthetic", "--pace", "max", "--seconds", "1e308", "--out",
                                "TMP/out/r.mcap"], ["argument --seconds", "'1e308'"]),
    ("record synthetic --fs 1e308", ["record", "--source", "synthetic", "--fs", "1e308", "--out", "TMP/out/r.mcap"],
     ["argument --fs", "at most 1e+15", "'1e308'"]),  # every number's bound (config.schema.MAX_MAGNITUDE)
    ("record synthetic --fs 1e12", ["record", "--source", "synthetic", "--fs", "1e12", "--out", "TMP/out/r.mcap"],
     ["1e+12 S/s", "lower fs_hz"]),
    # effect parameters whose range had no upper end: the filters' numbers overflowed (LinAlgError),
    # the magnet's flux ran out of the iron model's range (IndexError)
    *[(f"simulate --effect {e}", SIM[:2] + ["ecore_pm"] + SIM[3:] + ["--effect", e], [f"--effect {p}: must be in"])
      for e, p in (("frame_resonance=1e308", "frame_resonance.depth"),
                   ("charge_amp_highpass=1e30", "charge_amp_highpass.time_constant_s"),
                   ("integrator_leak=1e30", "integrator_leak.time_constant_s"),
                   ("magnet_thermal_drift=1e30", "magnet_thermal_drift.kelvin_per_s"))],
    # an empty name: pathlib's "." (a ValueError, or the current folder written into)
    ("simulate --out ''", SIM[:-1] + [""], ["argument --out", "''"]),
    # a rig file whose name no recording can carry: refused before the simulation, not after it
    ("simulate --rig ok.toml", SIM[:2] + ["RIG_TOML"] + SIM[3:], ["--rig", "ok.toml", "would name the rig 'ok'"]),
    # a folder for a recording's stem: '.' was a ValueError, 'DIR/' wrote DIR.csv beside the folder
    *[(f"simulate --out {o}", SIM[:-1] + [o], ["--out", ": a folder", "file stem"]) for o in ("TMP/out/", "TMP/..", ".")],
    ("simulate-sweep --out ''", ["simulate-sweep", "--out", ""], ["argument --out", "''"]),
    ("estimate ''", ["estimate", ""], ["argument path", "''"]),
    ("model predict M ''", ["model", "predict", "MODEL", "", "--out", "TMP/out/p.csv"], ["argument recording"]),
    ("compensate --model ''", COMP + FORCE + ["--model", ""], ["argument --model", "''"]),
    # files of the wrong kind
    ("force-map --out x.xyz", ["force-map", "--out", "TMP/out/map.xyz"], ["--out", "map.xyz", "png, ps"]),
    ("model predict GARBAGE", ["model", "predict", "GARBAGE", "TMP/none", "--out", "TMP/out/p.csv"],
     ["garbage.bin", "not a model file"]),
    ("compensate --model GARBAGE", COMP + FORCE + ["--model", "GARBAGE"], ["garbage.bin", "not a model file"]),
    ("compensate --force-file EMPTY", COMP + ["--model", "MODEL", "--force-file", "EMPTY_CSV", "--freq", "320"],
     ["empty.csv", "the file is empty"]),
    ("compensate freq=1e-300", COMP + ["--model", "MODEL", "--force", "offset=170,amp=40,freq=1e-300"],
     ["1e-300 Hz", "raise the frequency"]),
    # watch and ctl: zenoh's own errors and timeouts out of its range
    ("watch a//b", ["watch", "a//b", "--connect", DEAD, "--seconds", "0.2"], ["argument keyexpr", "'a//b'"]),
    ("watch ''", ["watch", "", "--connect", DEAD, "--seconds", "0.2"], ["argument keyexpr"]),
    ("watch --count 0", ["watch", "--count", "0", "--connect", DEAD, "--seconds", "0.2"], ["argument --count"]),
    ("watch --seconds -1", ["watch", "--seconds", "-1", "--connect", DEAD], ["argument --seconds", "'-1'"]),
    ("watch --quiet-after nan", ["watch", "--quiet-after", "nan", "--connect", DEAD, "--seconds", "0.2"],
     ["argument --quiet-after", "'nan'"]),
    ("ctl --timeout inf", ["ctl", "--connect", DEAD, "--timeout", "inf", "status"], ["argument --timeout", "'inf'"]),
    ("ctl --timeout 1e308", ["ctl", "--connect", DEAD, "--timeout", "1e308", "status"],
     ["argument --timeout", "86400"]),
    ("ctl --timeout 0", ["ctl", "--connect", DEAD, "--timeout", "0", "status"], ["argument --timeout", "'0'"]),
    ("ctl start_sweep --freqs nan", ["ctl", "--connect", DEAD, "--timeout", "0.2", "start_sweep", "--freqs", "nan"],
     ["argument --freqs", "'nan'"]),
    ("ctl start_sweep --dwell -1", ["ctl", "--connect", DEAD, "--timeout", "0.2", "start_sweep", "--dwell", "-1"],
     ["argument --dwell"]),
    ("ctl set_excitation --offset inf", ["ctl", "--connect", DEAD, "--timeout", "0.2", "set_excitation",
                                         "--offset", "inf"], ["argument --offset", "'inf'"]),
    # the daemon's compensator given a binary file as its model
    ("daemon [compensator] model = GARBAGE", ["daemon", "--config", "DAEMON_TOML"],
     ["garbage.bin", "not a model file"]),
]

#: Daemon files with one value out of what the daemon can run (section, key = value, words): each
#: was accepted, then an OverflowError or MemoryError traceback while building the ring, or six
#: faults of the running pipeline and exit 1, or blocks too large to ever be generated.
DAEMON_VALUES = [
    ("source", "ring_seconds = 1e308", "must be in (0, 60]"),
    ("source", "ring_seconds = 1e6", "must be in (0, 60]"),
    ("source", "block_samples = 1000000000", "must be at most 1e+06"),
    # blamed on the rate, not on a frequency outside "[1, 0.5] Hz"
    ("source", "fs_hz = 5", "5 Hz is too slow to play any frequency: 10 samples per period of the lowest"),
    ("daemon", "stats_interval_s = 1e308", "must be in (0, 3600]"),
    ("estimation", "periods = 1e308", "must be in [2, 1000]"),
    ("estimation", "hop_periods = 1e308", "must be in (0, 1000]"),
    ("estimation", "settle_periods = 1e308", "must be in [0, 1000]"),
    ("estimation", "min_hop_s = 1e308", "must be in [0, 3600]"),
    ("estimation", "max_fs_hz = 1e-300", "must be >= 1000"),
    ("sweep", "dwell_s = 1e308", "must be in (0, 86400]"),
    # its default frequencies from 40 Hz: 0.1 s there is 4 periods, the estimator skips 2 and fits 10
    ("sweep", "dwell_s = 0.1", "0.1 s is too short at 40 Hz, where a point needs 12 periods"),
]


def _files(tmp_path: Path, model_file: Path) -> dict[str, str]:
    garbage = tmp_path / "garbage.bin"
    garbage.write_bytes(GARBAGE)
    empty = tmp_path / "empty.csv"
    empty.write_bytes(b"")
    daemon = tmp_path / "daemon.toml"
    daemon.write_text(f'[daemon]\nbench = "errs"\nlog_dir = "{(tmp_path / "logs").as_posix()}"\n'
                      '[source]\nkind = "sim"\n[recording]\nenabled = false\n[zenoh]\nenabled = false\n'
                      f'[compensator]\nenabled = true\nmodel = "{garbage.as_posix()}"\n'
                      'force = "offset=170,amp=40,freq=320"\n', encoding="utf-8")
    rig = tmp_path / "ok.toml"  # the ecore_pm preset under another name
    rig.write_text((CONFIG_DIR / "rigs" / "ecore_pm.toml").read_text(encoding="utf-8"), encoding="utf-8")
    return {"GARBAGE": str(garbage), "EMPTY_CSV": str(empty), "MODEL": str(model_file), "DAEMON_TOML": str(daemon),
            "RIG_TOML": str(rig)}


@pytest.mark.parametrize("argv, words", [c[1:] for c in CASES], ids=[c[0] for c in CASES])
def test_edge_values_are_refused_with_one_line_naming_the_option(tmp_path, tmp_path_factory, monkeypatch, capsys,
                                                                 model_file, argv, words):
    files = _files(tmp_path, model_file)
    monkeypatch.chdir(tmp_path)  # an empty name must not become this folder, written into
    monkeypatch.setenv("STATE_DIRECTORY", str(tmp_path_factory.mktemp("state")))  # the daemon's lock, not ~'s
    before = sorted(tmp_path.rglob("*"))
    args = [files.get(a, a.replace("TMP/", f"{tmp_path}/")) for a in argv]
    code = main(args)
    err = capsys.readouterr().err
    assert "Traceback" not in err
    lines = [ln for ln in err.splitlines() if ": error: " in ln]
    assert code == 2 and len(lines) == 1, err
    for w in words:
        assert w in lines[0], lines[0]
    assert sorted(tmp_path.rglob("*")) == before  # nothing written, not even a folder


@pytest.mark.parametrize("section, setting, words", DAEMON_VALUES, ids=[f"[{s}] {k}" for s, k, _ in DAEMON_VALUES])
def test_a_daemon_file_value_the_daemon_cannot_run_is_refused_at_load(tmp_path, monkeypatch, capsys, section, setting,
                                                                      words):
    monkeypatch.setenv("STATE_DIRECTORY", str(tmp_path / "state"))  # the daemon's lock, not the user's
    toml = tmp_path / "daemon.toml"
    tables = {"daemon": f'bench = "errs"\nlog_dir = "{(tmp_path / "logs").as_posix()}"', "source": 'kind = "sim"',
              "recording": "enabled = false", "zenoh": "enabled = false"}
    tables[section] = "\n".join(filter(None, [tables.get(section), setting]))
    toml.write_text("".join(f"[{name}]\n{body}\n" for name, body in tables.items()), encoding="utf-8")
    code = main(["daemon", "--config", str(toml)])
    err = capsys.readouterr().err
    lines = [ln for ln in err.splitlines() if ": error: " in ln]
    assert code == 2 and len(lines) == 1 and "Traceback" not in err, err
    key = setting.split(" = ")[0]
    assert f"{toml} [{section}] {key}: {words}" in lines[0]
    assert not (tmp_path / "logs").exists()  # refused before anything was opened


def test_the_parsers_current_bound_is_the_rigs():
    """``--ipp`` is bounded while parsing (no numpy there) by the rig's own limit."""
    from hystbench.cli.args import SIM_MAX_IPP_A
    from hystbench.sim_backend.rig import MAX_CURRENT_A

    assert SIM_MAX_IPP_A == 2 * MAX_CURRENT_A


def test_records_block_bound_is_the_sources():
    from hystbench.acquisition.sources import MAX_BLOCK_SAMPLES
    from hystbench.cli import pipeline

    assert pipeline.MAX_BLOCK_SAMPLES == MAX_BLOCK_SAMPLES


def test_ctls_timeout_bound_is_the_clients():
    from hystbench.service.control import MAX_TIMEOUT_S
    from hystbench.cli import pipeline

    assert pipeline._MAX_TIMEOUT_S == MAX_TIMEOUT_S
