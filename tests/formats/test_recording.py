"""The recording interchange format: lossless round trip, speed, and one test per bad input."""

from __future__ import annotations

import json
import os
import re
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hystbench.formats import recording as rmod
from hystbench.formats.recording import (
    Recording, read_recording, read_sweep, sweep_stem, write_recording, write_sweep,
)
from hystbench.blocks import BlockFlags, SampleBlock
from hystbench.config import rig_names
from hystbench.errors import RecordingError

META = {"rig": "ecore_pm", "frequency_Hz": 320.0, "sample_rate_Hz": 1000.0, "current_pp_A": 1.4}


def make(tmp_path: Path, csv_text: str | None, meta: object = META, name: str = "rec") -> Path:
    """Write NAME.csv (if given) and NAME.json (a dict is dumped, a str written as is)."""
    if csv_text is not None:
        (tmp_path / f"{name}.csv").write_text(csv_text, encoding="utf-8")
    if meta is not None:
        text = meta if isinstance(meta, str) else json.dumps(meta)
        (tmp_path / f"{name}.json").write_text(text, encoding="utf-8")
    return tmp_path / name


def rows(n: int = 5, fs: float = 1000.0) -> str:
    """time_s,current_A,force_N; row i (file line i + 2) is 'i/fs, 0.5 i, 0.5 i + 1'."""
    return "time_s,current_A,force_N\n" + "".join(f"{i / fs!r},{0.5 * i!r},{0.5 * i + 1!r}\n" for i in range(n))


def bad(stem: Path, *fragments: str) -> str:
    """Read, expect a RecordingError whose message holds every fragment; return the message."""
    with pytest.raises(RecordingError) as info:
        read_recording(stem)
    msg = str(info.value)
    for f in fragments:
        assert f in msg, f"{f!r} not in {msg!r}"
    return msg


def sample_rec(n: int = 50, fs: float = 1000.0, **meta: object) -> Recording:
    t = np.arange(n) / fs
    return Recording(path=None, fs_hz=fs, channels={"current_A": np.sin(2 * np.pi * 50 * t),
                                                    "force_N": 3.0 + t, "temp_degC": 20 + 0 * t},
                     metadata={**META, "sample_rate_Hz": fs, **meta})


# --- round trip -----------------------------------------------------------------------------

finite = st.floats(allow_nan=False, allow_infinity=False, allow_subnormal=True)
json_scalar = st.none() | st.booleans() | st.integers(-2**53, 2**53) | finite | st.text(max_size=8)
extra_meta = st.dictionaries(st.text(min_size=1, max_size=8).filter(lambda k: k not in META),
                             json_scalar | st.lists(json_scalar, max_size=3), max_size=4)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(n=st.integers(1, 40), ncols=st.integers(1, 4), data=st.data(), extra=extra_meta,
       fs=st.floats(1e3, 1e6), t0=st.floats(-100, 100), rig=st.sampled_from(rig_names()))
def test_write_read_is_bit_identical(tmp_path, n, ncols, data, extra, fs, t0, rig):
    names = ["current_A", "force_N", "flux_Wb", "sense_V", "command_V", "gap_um"][:ncols]
    chans = {k: np.array(data.draw(st.lists(finite, min_size=n, max_size=n))) for k in names}
    meta = {"rig": rig, "frequency_Hz": fs / 7, "sample_rate_Hz": fs, "current_pp_A": 1.25, **extra}
    rec = Recording(path=None, fs_hz=fs, channels=chans, metadata=meta, t0_s=t0)
    write_recording(rec, tmp_path / "r", overwrite=True)
    back = read_recording(tmp_path / "r")
    assert list(back.channels) == names
    for k in names:
        assert back.channels[k].dtype == np.float64
        assert back.channels[k].view(np.uint64).tolist() == chans[k].view(np.uint64).tolist()
    assert back.metadata == meta and back.fs_hz == fs and back.t0_s == t0
    assert back.path == tmp_path / "r"


def test_one_second_at_100ks_six_channels_round_trips_exactly(tmp_path):
    """Speed is the benchmark's job (`python -m benchmarks csv`); here only the exact round trip."""
    rng = np.random.default_rng(1)
    rec = Recording(path=None, fs_hz=100_000.0, metadata={**META, "sample_rate_Hz": 100_000.0},
                    channels={k: rng.standard_normal(100_000) for k in
                              ["current_A", "force_N", "flux_Wb", "sense_V", "command_V", "shunt_V"]})
    write_recording(rec, tmp_path / "big")
    back = read_recording(tmp_path / "big.csv")
    assert all(np.array_equal(back.channels[k], rec.channels[k]) for k in rec.channels)


def test_reads_by_stem_csv_or_json_and_keeps_dots_in_stem(tmp_path):
    rec = sample_rec()
    write_recording(rec, tmp_path / "ecore_pm_320Hz_1.4App")
    for p in ["ecore_pm_320Hz_1.4App", "ecore_pm_320Hz_1.4App.csv", "ecore_pm_320Hz_1.4App.json"]:
        assert read_recording(tmp_path / p).path == tmp_path / "ecore_pm_320Hz_1.4App"


def test_accepts_crlf_bom_trailing_blank_lines_and_rounded_time(tmp_path):
    fs = 51_200.0  # %.9f time text errs by up to 2.6e-5 sample periods here
    text = "\ufefftime_s, current_A\r\n" + "".join(f"{i / fs:.9f},{i}\r\n" for i in range(300)) + "\r\n\r\n"
    rec = read_recording(make(tmp_path, text, {**META, "sample_rate_Hz": fs}))
    assert rec.n == 300 and list(rec.channels) == ["current_A"] and rec.channels["current_A"][-1] == 299


def test_properties_and_block_round_trip():
    fs = 1000.0
    blocks = [SampleBlock(first_index=i, fs_hz=fs, channels={"force_N": np.arange(i, i + 10.0)})
              for i in (100, 110, 120)]
    rec = Recording.from_blocks(blocks, {k: v for k, v in META.items() if k != "sample_rate_Hz"})
    assert (rec.rig, rec.frequency_hz, rec.current_pp_a, rec.n) == ("ecore_pm", 320.0, 1.4, 30)
    assert rec.duration_s == 0.03 and rec.t0_s == 0.1 and rec.time_s()[1] == 0.1 + 1 / fs
    block = rec.to_block()
    assert block.first_index == 100 and np.array_equal(block.channels["force_N"], np.arange(100.0, 130.0))
    assert rec.to_block(first_index=0).first_index == 0


def test_from_blocks_marks_clipping_and_refuses_lost_samples():
    a = SampleBlock(0, 1000.0, {"force_N": np.zeros(4)})
    b = SampleBlock(4, 1000.0, {"force_N": np.zeros(4)}, flags=BlockFlags.CLIP)
    assert Recording.from_blocks([a, b], META).metadata["clipped"] is True
    with pytest.raises(RecordingError, match="lost before block 1"):
        Recording.from_blocks([a, SampleBlock(4, 1000.0, {"force_N": np.zeros(4)}, flags=BlockFlags.GAP)], META)
    with pytest.raises(RecordingError, match="not contiguous"):
        Recording.from_blocks([a, SampleBlock(5, 1000.0, {"force_N": np.zeros(4)})], META)
    with pytest.raises(RecordingError, match="block 1 has"):
        Recording.from_blocks([a, SampleBlock(4, 1000.0, {"current_A": np.zeros(4)})], META)


def test_to_block_refuses_a_fractional_start():
    rec = Recording(None, 1000.0, {"force_N": np.zeros(3)}, META, t0_s=0.0004)
    with pytest.raises(RecordingError, match="first_index"):
        rec.to_block()


# --- bad input: sidecar ---------------------------------------------------------------------

def test_missing_sidecar(tmp_path):
    bad(make(tmp_path, rows(), None), "rec.json", "missing sidecar")


def test_missing_csv(tmp_path):
    bad(make(tmp_path, None), "rec.csv", "missing samples")


def test_missing_both(tmp_path):
    bad(tmp_path / "nothing", "nothing", "neither")


def test_sidecar_not_json(tmp_path):
    bad(make(tmp_path, rows(), '{\n  "rig": "ecore_pm",\n  "frequency_Hz": 320,,\n}'),
        "rec.json:3: column 23", "not valid JSON")


def test_sidecar_not_an_object(tmp_path):
    bad(make(tmp_path, rows(), "[1, 2]"), "rec.json", "JSON object")


def test_sidecar_duplicate_key(tmp_path):
    bad(make(tmp_path, rows(), '{"rig": "ecore", "rig": "ecore_pm"}'), "rec.json", "'rig' appears twice")


@pytest.mark.parametrize("key", rmod.REQUIRED_KEYS)
def test_sidecar_missing_key(tmp_path, key):
    meta = {k: v for k, v in META.items() if k != key}
    bad(make(tmp_path, rows(), meta), "rec.json", f"missing key {key!r}")


@pytest.mark.parametrize("key, value", [("rig", 5), ("frequency_Hz", "320"),
                                        ("sample_rate_Hz", True), ("current_pp_A", None)])
def test_sidecar_wrong_type(tmp_path, key, value):
    bad(make(tmp_path, rows(), {**META, key: value}), "rec.json", f"{key!r} must be a")


@pytest.mark.parametrize("key, value", [("sample_rate_Hz", 0), ("frequency_Hz", -5.0),
                                        ("current_pp_A", -1.0), ("sample_rate_Hz", 1e400)])
def test_sidecar_value_out_of_range(tmp_path, key, value):
    text = json.dumps({**META, key: value}).replace("Infinity", "1e400")  # parses to inf
    bad(make(tmp_path, rows(), text), "rec.json", f"{key!r} must be finite")


@pytest.mark.parametrize("key", [*rmod.REQUIRED_KEYS[1:], "start_time_s"])
def test_sidecar_integer_too_large_for_a_float_is_named(tmp_path, key):
    """JSON integers have no bound: 10^400 raised OverflowError in math.isfinite, a traceback."""
    text = json.dumps({**META, key: 12345}).replace("12345", "1" + "0" * 400)
    msg = bad(make(tmp_path, rows(), text), "rec.json", f"{key!r} must be")
    assert "... (401 characters)" in msg and len(msg) < 300, msg


def test_sidecar_nan_is_not_json(tmp_path):
    bad(make(tmp_path, rows(), {**META, "airgap_m": float("nan")}), "rec.json", "NaN is not valid JSON")


def test_sidecar_frequency_above_nyquist(tmp_path):
    bad(make(tmp_path, rows(), {**META, "frequency_Hz": 600.0}), "rec.json", "half of sample_rate_Hz")


def test_unknown_rig_lists_known(tmp_path):
    msg = bad(make(tmp_path, rows(), {**META, "rig": "ecore_magnet"}), "rec.json", "'ecore_magnet'")
    assert all(name in msg for name in rig_names())


# --- bad input: samples ---------------------------------------------------------------------

def test_empty_file(tmp_path):
    bad(make(tmp_path, ""), "rec.csv", "empty file")


def test_header_only(tmp_path):
    bad(make(tmp_path, "time_s,current_A\n\n"), "rec.csv", "header only")


def test_empty_header_line(tmp_path):
    bad(make(tmp_path, "\n0.0,1.0\n"), "rec.csv:1", "empty header")


def test_missing_time_column(tmp_path):
    bad(make(tmp_path, "time_ms,current_A\n0,1\n"), "rec.csv:1", "missing the time_s column", "time_ms")


def test_time_not_first_column(tmp_path):
    bad(make(tmp_path, "current_A,time_s\n1,0\n"), "rec.csv:1", "column 2")


@pytest.mark.parametrize("name", ["force", "force_", "force_10", "force N"])
def test_column_without_unit(tmp_path, name):
    bad(make(tmp_path, f"time_s,current_A,{name}\n0,1,2\n"), "rec.csv:1: column 3", "<channel>_<unit>")


def test_time_column_only(tmp_path):
    bad(make(tmp_path, "time_s\n0\n0.001\n"), "rec.csv:1:", "no channel columns")


def test_column_without_name(tmp_path):
    bad(make(tmp_path, "time_s,current_A,\n0,1,\n"), "rec.csv:1: column 3 has no name")


def test_known_channel_in_another_unit(tmp_path):
    bad(make(tmp_path, "time_s,current_mA\n0,1\n"), "rec.csv:1: column 2", "'current_A'")


def test_duplicate_column(tmp_path):
    bad(make(tmp_path, "time_s,force_N,current_A,force_N\n0,1,2,3\n"), "rec.csv:1: column 4", "repeats column 2")


def test_row_with_too_few_fields(tmp_path):
    text = rows().replace("0.003,1.5,2.5", "0.003,1.5")
    bad(make(tmp_path, text), "rec.csv:5:", "2 fields, the header has 3")


def test_row_with_too_many_fields(tmp_path):
    text = rows().replace("0.002,1.0,2.0", "0.002,1.0,2.0,7")
    bad(make(tmp_path, text), "rec.csv:4:", "4 fields, the header has 3")


def test_every_row_with_an_extra_field(tmp_path):
    text = "time_s,current_A\n0,1,9\n0.001,2,9\n"
    bad(make(tmp_path, text), "rec.csv:2:", "3 fields, the header has 2")


@pytest.mark.parametrize("field", ["abc", "1_0", "0x10", '"2.0"', "\u0661", "3.0;"])
def test_non_numeric_text(tmp_path, field):
    text = rows().replace("0.004,2.0,3.0", f"0.004,2.0,{field}")
    bad(make(tmp_path, text), f"rec.csv:6: column 3 (force_N): not a number: {field!r}")


def test_empty_field(tmp_path):
    bad(make(tmp_path, rows().replace("0.001,0.5,1.5", "0.001,,1.5")), "rec.csv:3: column 2 (current_A)", "empty")


def test_blank_line_between_samples(tmp_path):
    bad(make(tmp_path, rows().replace("1.5\n", "1.5\n\n", 1)), "rec.csv:4:", "empty line")


@pytest.mark.parametrize("field", ["nan", "-inf", "1e400"])
def test_non_finite_sample(tmp_path, field):
    bad(make(tmp_path, rows().replace("0.003,1.5,2.5", f"0.003,1.5,{field}")),
        "rec.csv:5: column 3 (force_N)", f"{field!r} is not a finite number")


def test_sidecar_not_utf8(tmp_path):
    (make(tmp_path, rows()).with_suffix(".json")).write_bytes(b'{"rig": "\xe9core"}')
    bad(tmp_path / "rec", "rec.json:1: not UTF-8")


def test_not_utf8(tmp_path):
    stem = make(tmp_path, rows())
    (tmp_path / "rec.csv").write_bytes(rows().encode().replace(b"0.002", b"0.00\xff"))
    bad(stem, "rec.csv:4:", "not UTF-8")


def test_non_uniform_time_names_the_line(tmp_path):
    lines = rows(20).splitlines()
    del lines[12]  # a lost sample: time jumps from 0.010 to 0.012 on file line 13
    bad(make(tmp_path, "\n".join(lines)), "rec.csv:13:", "time_s is non-uniform", "0.012 s follows 0.01 s")


def test_repeated_timestamp(tmp_path):
    lines = rows(20).splitlines()
    lines[8] = lines[7]
    bad(make(tmp_path, "\n".join(lines)), "rec.csv:9:", "time_s does not increase")


def test_constant_time(tmp_path):
    text = "time_s,current_A\n" + "1.0,2\n" * 5
    bad(make(tmp_path, text), "rec.csv:3:", "time_s does not increase")


def test_time_disagrees_with_sample_rate(tmp_path):
    bad(make(tmp_path, rows(10, fs=2000.0)), "rec.csv:3:", "sampled at 2000 Hz", "rec.json",
        "sample_rate_Hz 1000")


def test_time_drifts_slowly_from_sample_rate(tmp_path):
    fs_true = 1000.0 * (1 + 1e-5)  # 1e-5 relative: off by 1e-3 periods after 100 samples
    msg = bad(make(tmp_path, rows(400, fs=fs_true)), "rec.csv:", "sampled at 1000.01 Hz")
    assert 100 <= int(re.search(r"rec\.csv:(\d+):", msg).group(1)) <= 104


# --- bad input: in memory and on write ------------------------------------------------------

def test_non_finite_sample_in_memory():
    with pytest.raises(RecordingError, match=r"channel 'force_N' sample 2 is nan"):
        Recording(None, 1000.0, {"force_N": np.array([0, 1, np.nan])}, META)


def test_unitless_channel_in_memory():
    with pytest.raises(RecordingError, match=r"'force'.*<channel>_<unit>"):
        Recording(None, 1000.0, {"force": np.zeros(3)}, META)


def test_t0_too_large_for_float64_time_text():
    with pytest.raises(RecordingError, match=r"time_s starts at 1000000000\.0 s \(t0_s\), too far from 0.*start_time_s"):
        Recording(None, 1e5, {"force_N": np.zeros(3)}, {**META, "sample_rate_Hz": 1e5}, t0_s=1e9)
    Recording(None, 1e5, {"force_N": np.zeros(3)}, {**META, "sample_rate_Hz": 1e5}, t0_s=86400.0)


def test_rate_disagrees_with_metadata():
    with pytest.raises(RecordingError, match="differs from metadata sample_rate_Hz"):
        Recording(None, 2000.0, {"force_N": np.zeros(3)}, META)


def test_metadata_that_is_not_json(tmp_path):
    rec = sample_rec(note=object())
    with pytest.raises(RecordingError, match=r"rec\.json: metadata cannot be written as JSON"):
        write_recording(rec, tmp_path / "rec")
    assert list(tmp_path.iterdir()) == []


def test_nan_in_metadata_is_refused_on_write(tmp_path):
    with pytest.raises(RecordingError, match=r"rec\.json: metadata cannot be written as JSON"):
        write_recording(sample_rec(airgap_m=float("nan")), tmp_path / "rec")


def test_write_refuses_to_overwrite_unless_asked(tmp_path):
    write_recording(sample_rec(), tmp_path / "rec")
    with pytest.raises(RecordingError, match=r"rec\.csv: already exists"):
        write_recording(sample_rec(n=10), tmp_path / "rec")
    write_recording(sample_rec(n=10), tmp_path / "rec", overwrite=True)
    assert read_recording(tmp_path / "rec").n == 10


def test_crash_mid_write_leaves_old_recording_intact(tmp_path, monkeypatch):
    write_recording(sample_rec(n=50), tmp_path / "rec")
    before = {p.name: p.read_bytes() for p in tmp_path.iterdir()}

    def half_then_crash(fh, rec):
        fh.write("time_s,current_A\n0.0,1")
        raise KeyboardInterrupt

    monkeypatch.setattr(rmod, "_write_csv", half_then_crash)
    with pytest.raises(KeyboardInterrupt):
        write_recording(sample_rec(n=10), tmp_path / "rec", overwrite=True)
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir()} == before  # no temporaries left
    assert read_recording(tmp_path / "rec").n == 50


def test_new_files_follow_the_umask(tmp_path):
    csv_path, _ = write_recording(sample_rec(), tmp_path / "rec")
    umask = os.umask(0)
    os.umask(umask)
    assert csv_path.stat().st_mode & 0o777 == 0o666 & ~umask


# --- sweeps ---------------------------------------------------------------------------------

def sweep(tmp_path: Path) -> list[Recording]:
    recs = [sample_rec(frequency_Hz=f, current_pp_A=i) for f, i in [(320.0, 1.4), (40.0, 0.7), (40.0, 0.35)]]
    write_sweep(recs, tmp_path / "sw")
    return recs


def test_sweep_round_trip_sorted(tmp_path):
    recs = sweep(tmp_path)
    assert sorted(p.name for p in (tmp_path / "sw").iterdir())[:2] == ["ecore_pm_320Hz_1.4App.csv",
                                                                      "ecore_pm_320Hz_1.4App.json"]
    back = read_sweep(tmp_path / "sw")
    assert [(r.frequency_hz, r.current_pp_a) for r in back] == [(40.0, 0.35), (40.0, 0.7), (320.0, 1.4)]
    assert [r.path.name for r in back] == [sweep_stem(recs[2]), sweep_stem(recs[1]), sweep_stem(recs[0])]


def test_empty_sweep_folder(tmp_path):
    (tmp_path / "notes.txt").write_text("x")
    with pytest.raises(RecordingError, match=re.escape(str(tmp_path)) + ": no recordings"):
        read_sweep(tmp_path)


def test_sweep_folder_missing(tmp_path):
    with pytest.raises(RecordingError, match="nope: not a folder"):
        read_sweep(tmp_path / "nope")


def test_sweep_orphan_sidecar(tmp_path):
    sweep(tmp_path)
    (tmp_path / "sw" / "stray.json").write_text(json.dumps(META))
    with pytest.raises(RecordingError, match="sidecars without a .csv: stray.json"):
        read_sweep(tmp_path / "sw")


def test_sweep_upper_case_suffix(tmp_path):
    sweep(tmp_path)
    (tmp_path / "sw" / "X.CSV").write_text(rows())
    with pytest.raises(RecordingError, match="lower case: X.CSV"):
        read_sweep(tmp_path / "sw")


def test_sweep_bad_member_names_its_file(tmp_path):
    sweep(tmp_path)
    make(tmp_path / "sw", rows().replace("0.002", "0.00x"), {**META, "frequency_Hz": 80.0}, name="ecore_pm_80Hz")
    with pytest.raises(RecordingError, match=r"ecore_pm_80Hz\.csv:4: column 1 \(time_s\)"):
        read_sweep(tmp_path / "sw")


def test_sweep_of_several_rigs_reads_back_by_rig_then_frequency(tmp_path):
    """recording-format.md: a bench day's folder holds several rigs, told apart by the sidecar."""
    sweep(tmp_path)
    write_sweep([sample_rec(rig="ecore", frequency_Hz=f, current_pp_A=1.27) for f in (320.0, 80.0)], tmp_path / "sw")
    back = read_sweep(tmp_path / "sw")
    assert [(r.rig, r.frequency_hz, r.current_pp_a) for r in back] == [
        ("ecore", 80.0, 1.27), ("ecore", 320.0, 1.27),
        ("ecore_pm", 40.0, 0.35), ("ecore_pm", 40.0, 0.7), ("ecore_pm", 320.0, 1.4)]
    with pytest.raises(RecordingError) as info:
        read_sweep(tmp_path / "sw", one_rig=True)
    msg = str(info.value)
    assert msg.startswith(f"{tmp_path / 'sw'}: recordings of several rigs")
    assert "ecore: 2 recordings" in msg and "ecore_pm: 3 recordings" in msg and "folder of their own" in msg
    write_sweep([sample_rec(frequency_Hz=f) for f in (320.0, 40.0)], tmp_path / "one")
    assert [r.frequency_hz for r in read_sweep(tmp_path / "one", one_rig=True)] == [40.0, 320.0]  # one rig passes


def test_write_sweep_refuses_name_clash_before_writing(tmp_path):
    with pytest.raises(RecordingError, match="recordings 0 and 1 would both be written"):
        write_sweep([sample_rec(), sample_rec()], tmp_path / "sw")
    assert not (tmp_path / "sw").exists()


def test_a_sweep_that_fails_half_way_leaves_its_folder_as_it_was(tmp_path):
    """The third recording cannot be written (its metadata is not JSON): the two before it are not
    left behind, in a new folder or beside what an existing one held."""
    recs = [sample_rec(frequency_Hz=f) for f in (40.0, 80.0, 160.0)]
    recs[2].metadata["note"] = object()
    for folder in (tmp_path / "new", tmp_path / "old"):
        if folder.name == "old":
            write_sweep([sample_rec(frequency_Hz=320.0)], folder)
        before = sorted(p.name for p in folder.iterdir()) if folder.exists() else None
        with pytest.raises(RecordingError, match="ecore_pm_160Hz.*metadata cannot be written as JSON"):
            write_sweep(recs, folder)
        assert (sorted(p.name for p in folder.iterdir()) if folder.exists() else None) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["old"]  # no hidden folder left
