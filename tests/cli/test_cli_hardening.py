"""Issue 10: no wrong answer with exit 0 and no traceback at the command line.

Each case runs the real ``hystbench`` entry point (``cli.main``) and checks the exit status, the
one stderr line naming the option or file, and that nothing was left behind.
"""

from __future__ import annotations

import math
import os
import pty
import select
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from hystbench.cli.main import main
from hystbench.config import CONFIG_DIR, load_material
from hystbench.errors import ConfigError
from hystbench.sim_backend.rig import SimulatedRig

pytestmark = pytest.mark.slow(35)  # ~35 s: handed to a worker before lighter files (tests/conftest.py)


def run(args: list[str], capsys) -> tuple[int, str, str]:
    code = main([str(a) for a in args])
    cap = capsys.readouterr()
    return code, cap.out, cap.err


def error_line(err: str) -> str:
    """The one line that says what is wrong (argparse adds its usage above it); no traceback."""
    assert "Traceback" not in err
    lines = [ln for ln in err.splitlines() if ": error: " in ln]
    assert len(lines) == 1, err
    return lines[0]


def files_under(folder: Path) -> list[Path]:
    return sorted(p.relative_to(folder) for p in folder.rglob("*"))


def with_option(base: list[str], option: str, value: str) -> list[str]:
    args = list(base)
    if option in args:
        args[args.index(option) + 1] = value
    else:
        args += [option, value]
    return args


# --- 1. numbers the physics cannot take are refused while parsing, naming the option --------------
SIMULATE = ["simulate", "--rig", "voicecoil_ferrite", "--freq", "320", "--ipp", "1", "--duration", "0.01",
            "--out", "OUT/run"]
SWEEP = ["simulate-sweep", "--rig", "voicecoil_ferrite", "--freqs", "40,320", "--duration", "0.01", "--out", "OUT/s"]
RECORD = ["record", "--source", "sim", "--rig", "voicecoil_ferrite", "--pace", "max", "--seconds", "0.1",
          "--out", "OUT/r.mcap"]
COMPENSATE = ["compensate", "--direct", "--force", "offset=170,amp=40,freq=320", "--json"]
BAD = ["0", "-1", "nan", "inf"]

CASES = (
    [(SIMULATE, opt, v) for opt in ("--freq", "--ipp", "--duration", "--fs") for v in BAD]
    + [(SIMULATE, "--seed", "-1")]
    + [(SWEEP, "--freqs", v) for v in ("40,0", "nan", "40,-320", "inf,40", ",")]
    + [(SWEEP, "--ipp", v) for v in ("1,0", "-1")] + [(SWEEP, "--duration", "0"), (SWEEP, "--fs", "inf")]
    + [(RECORD, opt, v) for opt in ("--seconds", "--freq", "--ipp", "--fs") for v in BAD]
    + [(RECORD, "--block", "0"), (RECORD, "--seed", "-1")]
    + [(COMPENSATE, "--gain", v) for v in ("5", "0", "nan", "-0.5")]
    + [(COMPENSATE, opt, v) for opt in ("--measure", "--max-current", "--freq") for v in ("0", "inf")]
    + [(COMPENSATE, "--iterations", "-1"), (COMPENSATE, "--seed", "-1")]
    + [(["estimate", "OUT/x"], "--segment", "-1")]
)


@pytest.mark.parametrize("base, option, value", CASES, ids=[f"{b[0]} {o} {v}" for b, o, v in CASES])
def test_a_number_out_of_range_is_refused_naming_the_option(tmp_path, capsys, base, option, value):
    args = [a.replace("OUT", str(tmp_path)) for a in with_option(base, option, value)]
    code, out, err = run(args, capsys)
    assert code == 2
    assert f"argument {option}: " in error_line(err) and repr(value) in error_line(err)
    assert files_under(tmp_path) == []


def test_simulate_freq_0_no_longer_writes_the_presets_320_hz(tmp_path, capsys):
    """The tester's case: 0 Hz became the preset's 320 Hz through ``frequency_hz or preset``."""
    code, out, err = run(["simulate", "--freq", "0", "--ipp", "1", "--duration", "0.01", "--out", tmp_path / "z"],
                         capsys)
    assert code == 2 and "--freq" in error_line(err)
    assert files_under(tmp_path) == []


@pytest.mark.parametrize("kwargs", [
    {"frequency_hz": 0.0}, {"frequency_hz": -320.0}, {"frequency_hz": math.nan}, {"frequency_hz": math.inf},
    {"current_pp_a": math.nan}, {"current_pp_a": math.inf}, {"current_pp_a": -1.0},
    {"fs_hz": math.inf}, {"fs_hz": math.nan}, {"fs_hz": 0.0}, {"offset_a": math.nan},
])
def test_the_rig_itself_refuses_what_argparse_would(kwargs):
    """The daemon and library callers reach the rig without argparse: 0 must never mean "the preset"."""
    with pytest.raises(ConfigError, match="voicecoil_ferrite"):
        SimulatedRig("voicecoil_ferrite", **kwargs)


@pytest.mark.parametrize("seconds", [0.0, -1.0, math.nan, math.inf])
def test_the_rig_refuses_a_recording_of_no_length(seconds):
    rig = SimulatedRig("voicecoil_ferrite", frequency_hz=320.0, warmup_s=0.0)
    with pytest.raises(ConfigError, match="duration"):
        rig.record(seconds)


def test_a_clipped_recording_is_refused_not_written(tmp_path, capsys):
    """1000 A-pp is a 500 A peak against the preset ADC's +-2 A current full scale: every sample of the
    peaks is the full scale, so the recording would be no measurement of anything."""
    code, out, err = run(with_option(SIMULATE, "--ipp", "1000")[:-1] + [tmp_path / "run"], capsys)
    line = error_line(err)
    assert code == 2 and "clipped current_A (full scale ±2" in line and "--ipp" in line
    assert files_under(tmp_path) == []


@pytest.mark.parametrize("option, value, words", [("--duration", "1e-9", "less than one sample"),
                                                  ("--duration", "101", "1.01e+07 samples")])
def test_a_recording_too_short_or_too_long_to_hold_is_refused(tmp_path, capsys, option, value, words):
    code, out, err = run(with_option(SIMULATE, option, value)[:-1] + [tmp_path / "run"], capsys)
    assert code == 2 and option in error_line(err) and words in error_line(err)
    assert files_under(tmp_path) == []


# --- 2. effect parameters have physical ranges ----------------------------------------------------------
def test_a_negative_charge_amplifier_time_constant_is_refused(tmp_path, capsys):
    """The tester saw -43..58 N of force and a delay estimate from this."""
    code, out, err = run(SIMULATE[:-1] + [tmp_path / "run", "--effect", "charge_amp_highpass=-1"], capsys)
    line = error_line(err)
    assert code == 2
    assert "charge_amp_highpass.time_constant_s: must be in (0, 1e+06], got -1.0" in line
    assert files_under(tmp_path) == []


def test_a_frequency_above_nyquist_is_refused_once_the_sample_rate_is_known(tmp_path, capsys):
    base = SIMULATE[:-1] + [tmp_path / "run", "--fs", "1000", "--freq", "100"]
    code, out, err = run(with_option(base, "--rig", "ecore") + ["--effect", "mains_pickup.frequency_hz=600"],
                         capsys)
    assert code == 2 and "mains_pickup.frequency_hz: must be below fs/2 = 500 Hz, got 600.0" in error_line(err)
    # the voice coil's own frame modes (850 and 1175 Hz) cannot be sampled at 1 kS/s either
    code, out, err = run(base, capsys)
    assert code == 2 and "[effects.frame_resonance] frequencies_hz: must be below fs/2 = 500 Hz, got 850.0" in error_line(err)
    assert files_under(tmp_path) == []


def test_effects_lists_each_parameters_range(capsys):
    code, out, err = run(["effects"], capsys)
    assert code == 0
    assert "time_constant_s = 1.0 in (0, 1e+06]" in out
    assert "third_harmonic = 0.3 in [0, 1)" in out
    assert "frequencies_hz = [850.0, 1175.0] in (0, fs/2)" in out


# --- 3. outputs: refused up front, never partial, never a traceback ------------------------------------
@pytest.fixture
def a_file(tmp_path) -> Path:
    f = tmp_path / "taken"
    f.write_bytes(b"keep me")
    return f


@pytest.mark.parametrize("command", [["paper", "--quick"], ["fit-material"], ["force-map"],
                                     ["model", "fit", "no-such-sweep"]])
def test_out_on_an_existing_file_is_refused_and_the_file_kept(tmp_path, capsys, a_file, command):
    code, out, err = run(command + ["--out", a_file], capsys)
    assert code == 2 and str(a_file) in error_line(err)
    assert a_file.read_bytes() == b"keep me"
    assert files_under(tmp_path) == [Path("taken")]


@pytest.mark.parametrize("command, name", [(["paper", "--quick"], "p"), (["fit-material"], "m"),
                                           (["force-map"], "f.png"), (["model", "fit", "no-such-sweep"], "m.json"),
                                           (SIMULATE[:-2], "run")])
def test_out_in_a_folder_that_cannot_be_made_is_one_line(tmp_path, capsys, a_file, command, name):
    """A regular file where the folder should be: as unwritable as it gets, even for root."""
    code, out, err = run(command + ["--out", a_file / "sub" / name], capsys)
    assert code == 2 and str(a_file) in error_line(err)
    assert files_under(tmp_path) == [Path("taken")]


def test_force_map_replaces_an_existing_file_only_with_overwrite(tmp_path, capsys):
    png = tmp_path / "map.png"
    assert run(["force-map", "--out", png], capsys)[0] == 0
    first = png.read_bytes()
    assert first.startswith(b"\x89PNG")
    png.write_bytes(b"mine")
    code, out, err = run(["force-map", "--out", png], capsys)
    assert code == 2 and f"{png}: exists" in error_line(err) and "--overwrite" in error_line(err)
    assert png.read_bytes() == b"mine"
    assert run(["force-map", "--out", png, "--overwrite"], capsys)[0] == 0
    assert png.read_bytes() == first
    assert files_under(tmp_path) == [Path("map.png")]  # no temporary left beside it


def test_a_failed_model_fit_leaves_neither_file_nor_folder(tmp_path, capsys):
    """The output's folders are made for the command and removed again when it fails half-way
    (here: the sweep holds a recording that cannot be read)."""
    sweep = tmp_path / "sweep"
    sweep.mkdir()
    (sweep / "bad.csv").write_text("time_s,current_A\n0,oops\n")
    (sweep / "bad.json").write_text('{"rig": "ecore", "frequency_Hz": 40, "sample_rate_Hz": 1000, '
                                    '"current_pp_A": 1}')
    code, out, err = run(["model", "fit", sweep, "--out", tmp_path / "new" / "deeper" / "m.json"], capsys)
    assert code == 2 and "bad.csv" in error_line(err)
    assert not (tmp_path / "new").exists()
    assert files_under(tmp_path) == [Path("sweep"), Path("sweep/bad.csv"), Path("sweep/bad.json")]


def test_compensate_learn_gain_5_is_refused_before_any_work(capsys):
    """It ended in a ValueError traceback after the identification (LearningConfig's range)."""
    code, out, err = run(["compensate", "--learn", "--gain", "5", "--force", "offset=170,amp=40,freq=320"], capsys)
    assert code == 2 and "--gain" in error_line(err) and "(0, 1.5]" in error_line(err)
    assert out == ""


def test_a_refused_record_leaves_no_stub_log_and_the_retry_works(tmp_path, capsys):
    """The emulated generator refuses 60 kHz inside the pipeline, after the log was opened (and
    after the first idle samples): the log, with no sample taken with the output on, must go; the
    failure must be one line (the pipeline's log of it too); the same command with a good
    frequency must then succeed."""
    log = tmp_path / "run.mcap"
    args = ["record", "--seconds", "0.2", "--out", log]
    code, out, err = run(args + ["--freq", "60000"], capsys)
    assert code == 2 and "60000" in error_line(err) and str(log) in error_line(err)
    # one line: no traceback, no second report from the pipeline's log (a starved machine may add the
    # drivers' warnings that a stream fell behind: true, and not a report of this failure)
    said = [ln for ln in err.splitlines() if ": warning: " not in ln]
    assert len(said) == 1 and "Traceback" not in err, err
    assert not log.exists()
    code, out, err = run(args + ["--freq", "320"], capsys)
    assert code == 0 and log.stat().st_size > 0 and f"wrote {log}" in out


@pytest.mark.parametrize("args", [["effects"], ["rigs", "--json"], ["rigs"]])
def test_a_closed_pipe_is_not_a_traceback(args):
    """``hystbench effects | head -1``: the reader has gone before we write (deterministic: the read
    end is closed before the command starts)."""
    r, w = os.pipe()
    os.close(r)
    try:
        proc = subprocess.run([sys.executable, "-m", "hystbench", *args], stdout=w, stderr=subprocess.PIPE,
                              text=True, timeout=120)
    finally:
        os.close(w)
    assert proc.stderr == ""
    assert proc.returncode == 1


def test_record_verbose_into_a_closed_pipe_still_records_everything(tmp_path):
    """``record -v | head``: the estimates stop printing, the log is still written whole."""
    from hystbench.formats.mcaplog import iter_blocks

    log = tmp_path / "run.mcap"
    r, w = os.pipe()
    os.close(r)
    try:
        proc = subprocess.run([sys.executable, "-m", "hystbench", "record", "--source", "synthetic", "--pace", "max",
                               "--seconds", "0.5", "-v", "--out", str(log)], stdout=w, stderr=subprocess.PIPE,
                              text=True, timeout=120)
    finally:
        os.close(w)
    assert proc.stderr == "" and proc.returncode == 1  # 1: the final "wrote ..." line had no reader
    assert sum(b.n for b in iter_blocks(log)) == 50_000  # 0.5 s at 100 kS/s
    # ``replay LOG | head``: silent too (each estimate's listener said "Broken pipe" on stderr)
    r, w = os.pipe()
    os.close(r)
    try:
        proc = subprocess.run([sys.executable, "-m", "hystbench", "replay", str(log)], stdout=w,
                              stderr=subprocess.PIPE, text=True, timeout=120)
    finally:
        os.close(w)
    assert proc.stderr == "" and proc.returncode == 1


def test_an_error_naming_a_path_with_a_newline_is_still_one_line(tmp_path, capsys):
    code, out, err = run(["estimate", tmp_path / "a\nb.csv"], capsys)
    assert code == 2 and err.count("\n") == 1 and "a\\nb" in error_line(err)


@pytest.mark.parametrize("case", ["log", "sidecar", "rig"])
def test_a_pipe_for_a_file_is_refused_not_waited_on(tmp_path, case):
    """A FIFO with no writer where a file goes: opening it would block for ever. Refused by name (the
    timeout only bounds a failure of this test)."""
    fifo = tmp_path / {"log": "x.mcap", "sidecar": "t.json", "rig": "r.toml"}[case]
    os.mkfifo(fifo)
    if case == "sidecar":
        (tmp_path / "t.csv").write_text((Path(__file__).parents[1] / "data" / "real" / "magnet_N87_sine.csv").read_text())
    argv = {"log": ["estimate", str(fifo)], "sidecar": ["diagnose", str(tmp_path / "t.csv")],
            "rig": ["simulate", "--rig", str(fifo), "--freq", "80", "--ipp", "1", "--out", str(tmp_path / "s")]}[case]
    proc = subprocess.run([sys.executable, "-m", "hystbench", *argv], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    assert fifo.name in proc.stderr and ("not a file or folder" in proc.stderr or "not a regular file" in proc.stderr)


def _handles_sigterm(pid: int) -> bool:
    """Whether the process has a handler for SIGTERM (its SigCgt mask in /proc)."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("SigCgt:"):
            return bool(int(line.split()[1], 16) & (1 << (signal.SIGTERM - 1)))
    return False


def test_sigterm_ends_a_command_as_ctrl_c_does_leaving_no_partial_output(tmp_path):
    """``timeout`` or a service manager's SIGTERM: said, status 143, and no sweep folder, staging folder or
    temporary left (it used to kill the process where it stood). Sent once the handler is in place."""
    proc = subprocess.Popen([sys.executable, "-m", "hystbench", "simulate-sweep", "--freqs", "40,80,160,320",
                             "--ipp", "0.5,1,1.5", "--duration", "2", "--out", str(tmp_path / "sw")],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        while proc.poll() is None and not _handles_sigterm(proc.pid):  # polls the event, not a guess of time
            select.select([], [], [], 0.005)
        assert proc.poll() is None, "the command ran to its end without a SIGTERM handler"  # 12 x 2 s to simulate
        proc.send_signal(signal.SIGTERM)
        out, err = proc.communicate(timeout=300)
    finally:
        proc.kill()
    assert proc.returncode == 143 and "hystbench simulate-sweep: terminated" in err, err
    if "after the command finished" in err:  # the signal fell in an import's callback, which swallows it
        assert len(list((tmp_path / "sw").glob("*.csv"))) == 12 and sorted(p.name for p in tmp_path.iterdir()) == ["sw"]
    else:
        assert list(tmp_path.iterdir()) == []


def test_a_bench_day_into_a_closed_pipe_is_written_whole(tmp_path):
    """``simulate-bench-day --quick DAY | head -1``: all three rigs' folders, not the first two."""
    r, w = os.pipe()
    os.close(r)
    try:
        proc = subprocess.run([sys.executable, "-m", "hystbench", "simulate-bench-day", "--quick", str(tmp_path / "d")],
                              stdout=w, stderr=subprocess.PIPE, text=True, timeout=300)
    finally:
        os.close(w)
    assert proc.stderr == "" and proc.returncode == 1
    day = {p.name: len(list(p.glob("*.csv"))) for p in (tmp_path / "d").iterdir()}
    assert set(day) == {"voicecoil_ferrite", "ecore", "ecore_pm"} and all(n >= 2 for n in day.values())
    assert sorted(p.name for p in tmp_path.iterdir()) == ["d"]


def test_diagnose_into_a_closed_pipe_still_writes_its_report(tmp_path):
    """``diagnose TABLE --report DIR | head``: the report is written whole before the table is printed (the
    smallest vendored table: what is tested is the order of the writes, not the physics)."""
    table = Path(__file__).parents[1] / "data" / "real" / "magnet_N49_sine.csv"
    rep = tmp_path / "rep"
    r, w = os.pipe()
    os.close(r)
    try:
        proc = subprocess.run([sys.executable, "-m", "hystbench", "diagnose", str(table), "--report", str(rep)],
                              stdout=w, stderr=subprocess.PIPE, text=True, timeout=300)
    finally:
        os.close(w)
    assert proc.stderr == "" and proc.returncode == 1  # 1: the table had no reader
    page = (rep / "README.md").read_text()
    assert "rate_series" in page and "(interleaved)" in page and (rep / "loss_0_magnet_N49_sine.png").stat().st_size
    assert sorted(p.name for p in tmp_path.iterdir()) == ["rep"]  # no staging folder left


# --- 4. fit-material --refit writes to --out, never into the package -----------------------------------
def test_refit_writes_the_material_files_to_out_and_leaves_the_shipped_ones(tmp_path, capsys):
    shipped = sorted((CONFIG_DIR / "materials").glob("*.toml"))
    before = {p: (p.read_bytes(), p.stat().st_mtime_ns) for p in shipped}
    out = tmp_path / "fit"
    code, stdout, err = run(["fit-material", "--refit", "--out", out, "--json"], capsys)
    assert code == 0, err
    assert {p: (p.read_bytes(), p.stat().st_mtime_ns) for p in shipped} == before
    for name in ("M330-50A", "M130-27S"):
        toml = out / f"{name}.toml"
        assert load_material(toml)["name"] == name and "[preisach]" in toml.read_text()
        assert str(toml) in stdout
    assert not any(p.name.startswith(".") for p in tmp_path.iterdir())  # the staging folder is gone
    # nor into the package's own folder, even with --overwrite (it rewrote the shipped files there)
    code, stdout, err = run(["fit-material", "--refit", "--out", CONFIG_DIR / "materials", "--overwrite"], capsys)
    assert code == 2 and "the command reads" in error_line(err)
    assert {p: (p.read_bytes(), p.stat().st_mtime_ns) for p in shipped} == before


# --- 5. force-map says what it draws ---------------------------------------------------------------------
@pytest.mark.parametrize("rig, kind", [("voicecoil_ferrite", "voicecoil"), ("toroid", "toroid")])
def test_force_map_of_a_voice_coil_or_toroid_names_the_e_core_presets(tmp_path, capsys, rig, kind):
    code, out, err = run(["force-map", "--rig", rig, "--out", tmp_path / "f.png"], capsys)
    line = error_line(err)
    assert code == 2 and rig in line and kind in line and "E-cores only" in line
    assert "ecore, ecore_pm" in line and "geometry" not in line
    assert files_under(tmp_path) == []


# --- 6. progress on a terminal's stderr, stdout line by line when piped -----------------------------------
def test_stdout_is_line_buffered_when_piped():
    code = ("import sys; from hystbench.cli.main import main; main(['rigs', '--json']); "
            "sys.stderr.write(str(sys.stdout.line_buffering))")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0 and proc.stdout.startswith("[")
    assert proc.stderr == "True"


def test_identify_shows_progress_on_a_terminal_and_keeps_stdout_clean(tmp_path, capsys):
    sweep = tmp_path / "sweep"
    assert run(["simulate-sweep", "--rig", "ecore", "--freqs", "80,320", "--ipp", "1.27", "--duration", "0.1",
                "--out", sweep], capsys)[0] == 0
    master, slave = pty.openpty()
    env = {**os.environ, "TERM": "xterm", "COLUMNS": "200"}
    proc = subprocess.Popen([sys.executable, "-m", "hystbench", "identify", str(sweep)], stdout=subprocess.PIPE,
                            stderr=slave, env=env)
    os.close(slave)
    seen = b""
    while True:  # until the child closes its end (EIO on Linux)
        try:
            chunk = os.read(master, 4096)
        except OSError:
            break
        if not chunk:
            break
        seen += chunk
    os.close(master)
    stdout = proc.stdout.read().decode()
    assert proc.wait(timeout=120) == 0
    assert b"the method's delays" in seen  # the bar was drawn on the terminal (then erased)
    assert "theta_hyst" in stdout and "method's delays (" not in stdout


def test_no_progress_bar_when_stderr_is_not_a_terminal(tmp_path, capsys):
    sweep = tmp_path / "sweep"
    run(["simulate-sweep", "--rig", "ecore", "--freqs", "80,320", "--ipp", "1.27", "--duration", "0.1",
         "--out", sweep], capsys)
    code, out, err = run(["identify", sweep], capsys)
    assert code == 0 and err == ""


@pytest.mark.parametrize("args, says", [
    (["--fs", "50000"], "--fs: not taken by --source bench; the bench file sets them"),
    (["--seed", "3", "--pace", "max"], "--pace, --seed: not taken by --source bench"),
    (["--source", "synthetic", "--effect", "sensor_noise=off"], "--effect: not taken by --source synthetic"),
    (["--source", "sim", "--bench-file", "bench.toml"], "--bench-file: not taken by --source sim"),
    (["--rig", "toroid"], "--rig: 'toroid' has no force channel for the emulated bench's charge amplifier"),
])
def test_a_record_option_its_source_would_ignore_is_refused(tmp_path, capsys, args, says):
    """``record --fs 50000`` on the bench source recorded at the bench file's 100 kHz, ``--rig toroid``
    said ecore_pm in the log (or, as the emulated rig, streamed no force for 20 s): refused by option,
    nothing written."""
    log = tmp_path / "r.mcap"
    code, out, err = run(["record", "--seconds", "0.1", "--out", log, *args], capsys)
    assert code == 2 and says in error_line(err) and out == "" and not log.exists()


def test_record_rig_is_the_emulated_benchs_rig(tmp_path, capsys):
    """``--rig`` with the bench source sets the emulated rig (it was ignored: the log said ecore_pm)."""
    from hystbench.formats.mcaplog import log_metadata

    log = tmp_path / "r.mcap"
    code, out, err = run(["record", "--seconds", "0.2", "--out", log, "--rig", "ecore"], capsys)
    assert code == 0 and log_metadata(log)["recording"]["rig"] == "ecore"


@pytest.mark.parametrize("args", [
    ["simulate", "--rig", "voicecoil_ferrite", "--freq", "320", "--ipp", "1", "--duration", "0.01",
     "--effect", "iron_saturation=on", "--out", "OUT/run"],
    ["simulate-sweep", "--rig", "voicecoil_ferrite", "--freqs", "40,320", "--duration", "0.01",
     "--effect", "magnet_thermal_drift=1", "--out", "OUT/s"],
    ["record", "--source", "sim", "--rig", "ecore", "--seconds", "0.1", "--effect", "magnet_eddy_currents=on",
     "--out", "OUT/r.mcap"],
])
def test_an_effect_switched_on_where_it_does_not_act_is_refused(tmp_path, capsys, args):
    """The sidecar listed the effect and the samples were byte for byte those without it."""
    args = [str(a).replace("OUT", str(tmp_path / "out")) for a in args]
    code, out, err = run(args, capsys)
    assert code == 2 and "--effect: " in error_line(err) and "does not act on" in error_line(err)
    assert not (tmp_path / "out").exists()


def test_a_segment_asked_of_a_recording_is_refused_not_ignored(tmp_path, capsys):
    """--segment picks an operating point of an MCAP log; given a CSV recording it was ignored and the
    whole recording estimated, exit 0."""
    stem = tmp_path / "r"
    assert main(["simulate", "--rig", "ecore_pm", "--freq", "320", "--ipp", "1", "--duration", "0.02",
                 "--out", str(stem)]) == 0
    capsys.readouterr()
    code, out, err = run(["estimate", str(stem), "--segment", "3"], capsys)
    assert code == 2 and out == ""
    assert f"--segment 3: {stem} is a recording (one operating point); --segment picks one of an MCAP log's" \
        in error_line(err)
    assert run(["estimate", str(stem)], capsys)[0] == 0
