"""Hostile or broken recordings, sidecars and material tables (issue 26, part 5): every one is a
RecordingError naming the file (and line or column), read in bounded memory, never a traceback.

The memory figures are taken in a child process (its own peak RSS, ``ru_maxrss``) so that the
test run's other allocations do not count; they are bounds on bytes, never on time.
"""

from __future__ import annotations

import json
import re
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from hystbench.cli.main import main as cli_main
from hystbench.errors import RecordingError
from hystbench.formats import material_data, text_chunks
from hystbench.formats.material_data import read_material_table, read_waveform_table
from hystbench.formats.recording import MAX_COLUMN_NAME_CHARS, read_recording
from hystbench.formats.small_files import MAX_SIDECAR_BYTES

META = {"rig": "ecore_pm", "frequency_Hz": 320.0, "sample_rate_Hz": 100000.0, "current_pp_A": 1.4}
REAL = Path(__file__).resolve().parents[1] / "data" / "real"


def make(folder: Path, csv_bytes: bytes, meta: object = META, name: str = "rec") -> Path:
    (folder / f"{name}.csv").write_bytes(csv_bytes)
    (folder / f"{name}.json").write_text(meta if isinstance(meta, str) else json.dumps(meta))
    return folder / name


# --- CSV -------------------------------------------------------------------------------------

def test_a_200_kb_header_field_is_named_not_a_csv_traceback(tmp_path: Path, capsys) -> None:
    """Before: ``_csv.Error: field larger than field limit (131072)`` escaped as a traceback."""
    stem = make(tmp_path, b"time_s,current_A," + b"x" * 200_000 + b"\n0,1,2\n")
    with pytest.raises(RecordingError) as err:
        read_recording(stem)
    msg = str(err.value)
    assert msg.startswith(f"{stem}.csv:1: column 3: a name of 200000 characters")
    assert len(msg) < 300  # the field is not quoted whole
    assert cli_main(["estimate", str(stem)]) == 2
    out = capsys.readouterr().err
    assert f"{stem}.csv:1: column 3" in out and "Traceback" not in out and out.count("\n") == 1


def test_a_quoted_header_field_over_the_csv_limit_is_named(tmp_path: Path) -> None:
    """A quoted field hides its commas from a plain split; csv's own limit must not escape either."""
    field = '"' + "ab," * 60_000 + '"'
    stem = make(tmp_path, f"time_s,{field}\n0,1\n".encode())
    with pytest.raises(RecordingError, match=rf"^{stem}\.csv:1: "):
        read_recording(stem)


def test_column_names_up_to_the_cap_are_read(tmp_path: Path) -> None:
    name = "c" * (MAX_COLUMN_NAME_CHARS - 2) + "_V"
    rec = read_recording(make(tmp_path, f"time_s,{name}\n0,1\n1e-05,2\n".encode()))
    assert list(rec.channels) == [name] and rec.channels[name].tolist() == [1.0, 2.0]
    long = "c" * (MAX_COLUMN_NAME_CHARS - 1) + "_V"
    with pytest.raises(RecordingError, match=rf"column 2: a name of {MAX_COLUMN_NAME_CHARS + 1} characters"):
        read_recording(make(tmp_path, f"time_s,{long}\n0,1\n".encode(), name="long"))


@pytest.mark.parametrize("where", ["header", "row"])
def test_a_line_past_max_line_bytes_is_refused_with_its_line_number(tmp_path: Path, monkeypatch, where) -> None:
    monkeypatch.setattr(text_chunks, "MAX_LINE_BYTES", 4096)
    monkeypatch.setattr(text_chunks, "BLOCK_BYTES", 1000)  # the line spans several blocks
    long = b"1" * 5000
    data = (b"time_s,force_N," + long + b"\n0,1,2\n" if where == "header"
            else b"time_s,force_N\n0,1\n1e-05,2\n" + long + b",3\n4,5\n")
    stem = make(tmp_path, data)
    line = 1 if where == "header" else 4
    with pytest.raises(RecordingError, match=rf"^{stem}\.csv:{line}: a line longer than 4096 bytes"):
        read_recording(stem)
    # a line of exactly the cap is read (here: a row with the cap's length of digits)
    row = b"0," + b"0" * (4096 - 2)
    rec = read_recording(make(tmp_path, b"time_s,force_N\n" + row + b"\n", name="ok"))
    assert rec.n == 1 and rec.channels["force_N"].tolist() == [0.0]


def test_a_long_bad_field_is_quoted_short(tmp_path: Path) -> None:
    stem = make(tmp_path, b"time_s,force_N\n0,1\n1e-05," + b"z" * 300_000 + b"\n")
    with pytest.raises(RecordingError, match=rf"^{stem}\.csv:3: column 2 \(force_N\): not a number") as err:
        read_recording(stem)
    assert len(str(err.value)) < 300
    big = b"9" * 400 + b"e9"  # a finite-looking field that reads as inf
    with pytest.raises(RecordingError, match="is not a finite number") as err:
        read_recording(make(tmp_path, b"time_s,force_N\n0," + big + b"\n", name="inf"))
    assert len(str(err.value)) < 300


def test_many_columns_over_many_blank_lines_do_not_size_the_array(tmp_path: Path) -> None:
    """The sample array was sized columns x lines before a row was read: 20 000 columns over two
    million blank lines asked numpy for 320 GB (a MemoryError traceback).  A row of k fields takes
    2k bytes, so the file's size bounds the rows as well."""
    header = ",".join(["time_s"] + [f"c{j}_V" for j in range(20_000)]).encode()
    stem = make(tmp_path, header + b"\n" + b"\n" * 2_000_000)
    with pytest.raises(RecordingError, match=rf"^{stem}\.csv: header only, no samples"):
        read_recording(stem)


def _child_peak(script: str, *args: str) -> dict:
    """Run ``script`` in a fresh interpreter; it prints a JSON dict (peak RSS figures in bytes)."""
    proc = subprocess.run([sys.executable, "-c", textwrap.dedent(script), *args], capture_output=True,
                          text=True, timeout=300)  # a guard against a hang, not a timing
    assert proc.returncode == 0, proc.stderr
    return json.loads(proc.stdout.strip().splitlines()[-1])


_READ_PEAK = """
    import json, resource, sys
    from hystbench.errors import RecordingError
    from hystbench.formats.recording import read_recording
    def peak(): return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
    before = peak()
    try:
        rec = read_recording(sys.argv[1]); outcome, n = "ok", rec.n
    except Exception as err:  # the caller says which outcome is right; a traceback is one too
        outcome, n = (str(err) if isinstance(err, RecordingError) else repr(err))[:200], 0
    print(json.dumps({"before": before, "after": peak(), "outcome": outcome, "n": n}))
"""


def test_one_huge_line_is_refused_in_bounded_memory(tmp_path: Path) -> None:
    """Before: a file with no line end was held whole, then decoded and split (3x its size; a 2 GB
    header field took 6.5 GB).  Now reading stops at MAX_LINE_BYTES."""
    size = 48 << 20
    with open(tmp_path / "rec.csv", "wb") as fh:
        fh.write(b"time_s,current_A,")
        for _ in range(size // (1 << 20)):
            fh.write(b"x" * (1 << 20))
        fh.write(b"\n0,1,2\n")
    (tmp_path / "rec.json").write_text(json.dumps(META))
    got = _child_peak(_READ_PEAK, str(tmp_path / "rec"))
    assert got["after"] - got["before"] < size // 4, got  # before the fix: about 3 x size
    assert got["outcome"].startswith(f"{tmp_path / 'rec.csv'}:1: a line longer than"), got


def test_a_large_csv_needs_its_samples_not_its_text(tmp_path: Path) -> None:
    """A valid file's peak is its float64 samples plus a few text blocks, not a multiple of the
    text: here 600 000 rows x 4 columns (19 MB of samples) in 30+ MB of text."""
    n, fs = 600_000, 100_000.0
    t = np.arange(n) / fs
    with open(tmp_path / "big.csv", "w") as fh:
        fh.write("time_s,current_A,force_N,flux_Wb\n")
        for a in range(0, n, 100_000):
            fh.write("".join(f"{x!r},0.123456789,175.00390625,-4.99e-05\n" for x in t[a:a + 100_000].tolist()))
    (tmp_path / "big.json").write_text(json.dumps(META))
    text_bytes = (tmp_path / "big.csv").stat().st_size
    got = _child_peak(_READ_PEAK, str(tmp_path / "big"))
    assert got["outcome"] == "ok" and got["n"] == n
    samples = 4 * n * 8
    assert got["after"] - got["before"] < samples + 8 * text_chunks.BLOCK_BYTES + (16 << 20), (got, text_bytes)


# --- sidecars --------------------------------------------------------------------------------

def test_a_sidecar_over_max_sidecar_bytes_is_refused(tmp_path: Path) -> None:
    stem = make(tmp_path, b"time_s,force_N\n0,1\n",
                meta=json.dumps({**META, "notes": "n" * MAX_SIDECAR_BYTES}))
    with pytest.raises(RecordingError, match=rf"^{stem}\.json: larger than {MAX_SIDECAR_BYTES} bytes; a sidecar"):
        read_recording(stem)
    fits = make(tmp_path, b"time_s,force_N\n0,1\n", name="fits",
                meta=json.dumps({**META, "notes": "n" * (MAX_SIDECAR_BYTES - 200)}))
    assert len(read_recording(fits).metadata["notes"]) == MAX_SIDECAR_BYTES - 200


@pytest.mark.parametrize("text, why", [
    ("[" * 100_000 + "]" * 100_000, "JSON nested too deeply"),
    ('{"rig": ' + '{"a": ' * 50_000 + "1" + "}" * 50_001, "JSON nested too deeply"),
    ('{"rig": "ecore_pm", "n": ' + "1" * 5000 + "}", "not valid JSON"),
])
def test_sidecars_that_break_the_json_parser_are_named(tmp_path: Path, text: str, why: str) -> None:
    """Before: RecursionError and int()'s digit limit (a ValueError) escaped as tracebacks."""
    stem = make(tmp_path, b"time_s,force_N\n0,1\n", meta=text)
    with pytest.raises(RecordingError, match=rf"^{stem}\.json: {why}"):
        read_recording(stem)


def test_a_sample_rate_of_1e308_is_named_as_the_rate_not_non_uniform_time(tmp_path: Path) -> None:
    """Before: 'time_s is non-uniform: 1e-05 s follows 0.0 s, a step of 1e-05 s where most are
    1e-05 s': a tolerance of 1e-3 / 1e308 s is below the float resolution of every step."""
    rows = "".join(f"{i / 1e5!r},{i % 7}\n" for i in range(1000)).encode()
    stem = make(tmp_path, b"time_s,current_A\n" + rows, meta={**META, "sample_rate_Hz": 1e308})
    with pytest.raises(RecordingError) as err:
        read_recording(stem)
    msg = str(err.value)
    assert "non-uniform" not in msg
    assert re.search(r"time_s is sampled at 100000 Hz but rec\.json says sample_rate_Hz 1e\+308", msg), msg
    # a column that really is non-uniform is still named so, whatever the sidecar's rate
    t = np.arange(1000) / 1e5
    t[500:] += 0.5e-5
    bad = "".join(f"{x!r},1\n" for x in t.tolist()).encode()
    stem = make(tmp_path, b"time_s,current_A\n" + bad, meta={**META, "sample_rate_Hz": 1e308}, name="jump")
    with pytest.raises(RecordingError, match=rf"^{stem}\.csv:502: time_s is non-uniform"):
        read_recording(stem)


# --- material tables -------------------------------------------------------------------------

def test_material_table_and_sidecar_are_bounded_and_named(tmp_path: Path, monkeypatch) -> None:
    for suffix in (".csv", ".json"):
        shutil.copy(REAL / f"magnet_N87_sine{suffix}", tmp_path / f"t{suffix}")
    size = (tmp_path / "t.csv").stat().st_size
    monkeypatch.setattr(material_data, "MAX_TABLE_BYTES", size - 1)
    with pytest.raises(RecordingError, match=rf"^{tmp_path / 't.csv'}: larger than {size - 1} bytes.*MAX_TABLE_BYTES"):
        read_material_table(tmp_path / "t.csv")
    monkeypatch.setattr(material_data, "MAX_TABLE_BYTES", size)
    assert len(read_material_table(tmp_path / "t.csv")) == 964
    meta = json.loads((tmp_path / "t.json").read_text())
    (tmp_path / "t.json").write_text('{"material": ' + "[" * 100_000)
    with pytest.raises(RecordingError, match=rf"^{tmp_path / 't.json'}: "):
        read_material_table(tmp_path / "t.csv")
    (tmp_path / "t.json").write_text(json.dumps(meta))
    lines = (tmp_path / "t.csv").read_text().splitlines()
    lines[3] = lines[3].split(",")[0] + "," + "q" * 100_000 + ",1"
    (tmp_path / "t.csv").write_text("\n".join(lines) + "\n")
    monkeypatch.setattr(material_data, "MAX_TABLE_BYTES", 1 << 20)
    with pytest.raises(RecordingError, match=r":4: column 2 \(flux_density_peak_T\): 'qqq") as err:
        read_material_table(tmp_path / "t.csv")
    assert len(str(err.value)) < 300



def test_waveform_table_is_bounded_and_named(tmp_path: Path, monkeypatch) -> None:
    for suffix in (".csv", ".json"):
        shutil.copy(REAL / "mag-net-hub" / f"maghub_3C90_sequence{suffix}", tmp_path / f"w{suffix}")
    size = (tmp_path / "w.csv").stat().st_size
    monkeypatch.setattr(material_data, "MAX_TABLE_BYTES", size - 1)
    with pytest.raises(RecordingError, match=rf"^{tmp_path / 'w.csv'}: larger than {size - 1} bytes; a waveform "
                                             r"table .*MAX_TABLE_BYTES"):
        read_waveform_table(tmp_path / "w.csv")
    monkeypatch.setattr(material_data, "MAX_TABLE_BYTES", size)
    assert len(read_waveform_table(tmp_path / "w.csv")) == 6
    lines = (tmp_path / "w.csv").read_text().splitlines()
    lines[2] = "q" * 100_000 + lines[2][lines[2].index(","):]
    (tmp_path / "w.csv").write_text("\n".join(lines) + "\n")
    monkeypatch.setattr(material_data, "MAX_TABLE_BYTES", 1 << 20)
    with pytest.raises(RecordingError, match=r"w\.csv:3: column 1 \(B_t_0\): 'qqq") as err:
        read_waveform_table(tmp_path / "w.csv")
    assert len(str(err.value)) < 300
    (tmp_path / "w.json").write_text('{"kind": "waveform", "units": ' + "[" * 100_000)
    with pytest.raises(RecordingError, match=rf"^{tmp_path / 'w.json'}: "):
        read_waveform_table(tmp_path / "w.csv")
