"""The CSV samples read a chunk of lines at a time (issue 10): the same arrays whatever the line
ends and wherever the chunks are cut, every error still at its line and column, bounded memory.

Chunk boundaries are moved by setting ``text_chunks.BLOCK_BYTES`` small, so that small files
cross many of them; one multi-megabyte file checks the default block size.
"""

from __future__ import annotations

import io
import json
import tracemalloc
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hystbench.formats import text_chunks as tc
from hystbench.formats.recording import read_recording
from hystbench.errors import RecordingError

FS = 1000.0
META = {"rig": "ecore_pm", "frequency_Hz": 320.0, "sample_rate_Hz": FS, "current_pp_A": 1.4}
NAMES = ["time_s", "current_A", "force_N"]


def columns(n: int, seed: int = 0) -> np.ndarray:
    """(3, n): uniform time, then two channels of arbitrary float64 (full precision, any sign)."""
    rng = np.random.default_rng(seed)
    return np.vstack([np.arange(n) / FS, rng.standard_normal(n), rng.standard_normal(n) * 1e3])


def lines_of(cols: np.ndarray, names: list[str] = NAMES) -> list[str]:
    """Header and one line per row; repr is the shortest text that reads back to the same float."""
    return [",".join(names)] + [",".join(map(repr, row)) for row in cols.T.tolist()]


def write(tmp_path: Path, lines: list[str], eol: str = "\n", end: str = "\n", raw: bytes | None = None) -> Path:
    """rec.csv from lines joined by ``eol`` and followed by ``end`` (or the bytes ``raw``), and rec.json."""
    (tmp_path / "rec.csv").write_bytes(raw if raw is not None else (eol.join(lines) + end).encode())
    (tmp_path / "rec.json").write_text(json.dumps(META))
    return tmp_path / "rec"


def bit_equal(a: np.ndarray, b: np.ndarray) -> bool:
    return a.dtype == b.dtype == np.float64 and a.view(np.uint64).tolist() == b.view(np.uint64).tolist()


# --- text_chunks ----------------------------------------------------------------------------

line_text = st.text(st.sampled_from("0123456789,.e-x é€😀\t"), max_size=12)


@settings(max_examples=300, deadline=None)
@given(lines=st.lists(line_text, min_size=1, max_size=25), data=st.data(),
       bom=st.booleans(), block=st.integers(1, 40))
def test_chunks_are_whole_lines_that_rebuild_the_text(lines, data, bom, block):
    ends = data.draw(st.lists(st.sampled_from(["\n", "\r\n", "\r"]), min_size=len(lines), max_size=len(lines)))
    last = data.draw(st.booleans())  # the last line with or without its line end
    raw = ("\ufeff" if bom else "") + "".join(l + e for l, e in zip(lines, ends))
    if not last:
        raw = raw[:-len(ends[-1])]
    expected = raw.removeprefix("\ufeff").replace("\r\n", "\n").replace("\r", "\n")  # the whole text at once
    chunks = list(tc.text_chunks(io.BytesIO(raw.encode()), "f.csv", block_bytes=block))
    assert "".join(text for _, text in chunks) == expected
    seen = 0
    for first, text in chunks:
        assert first == 1 + seen  # each chunk starts a line, and knows which
        assert text and (text.endswith("\n") or (first, text) == chunks[-1])
        seen += text.count("\n")
    body = io.BytesIO(raw.encode())
    assert expected.count("\n") <= tc.count_line_ends(body, block) <= expected.count("\n") + len(raw.encode()) // block


def test_a_line_longer_than_many_blocks_is_one_chunk():
    long = "1," * 5000 + "1"
    chunks = list(tc.text_chunks(io.BytesIO(f"a\n{long}\nb".encode()), "f.csv", block_bytes=7))
    assert "".join(t for _, t in chunks) == f"a\n{long}\nb"
    assert any(t == long + "\n" or t.endswith(long + "\n") for _, t in chunks)


# --- the same arrays, whatever the file looks like ------------------------------------------

@settings(max_examples=80, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(n=st.integers(1, 60), eol=st.sampled_from(["\n", "\r\n", "\r"]), bom=st.booleans(),
       end=st.sampled_from(["", "EOL", "EOL EOL", "EOL  \t EOL EOL"]), block=st.integers(1, 300),
       seed=st.integers(0, 2**32 - 1))
def test_reads_the_written_values_whatever_line_ends_and_chunk_cuts(tmp_path, monkeypatch, n, eol, bom, end,
                                                                    block, seed):
    cols = columns(n, seed)
    text = eol.join(lines_of(cols)) + end.replace("EOL", eol)
    monkeypatch.setattr(tc, "BLOCK_BYTES", block)
    rec = read_recording(write(tmp_path, [], raw=(b"\xef\xbb\xbf" if bom else b"") + text.encode()))
    assert rec.n == n and list(rec.channels) == NAMES[1:] and rec.t0_s == 0.0
    assert bit_equal(rec.channels["current_A"], cols[1]) and bit_equal(rec.channels["force_N"], cols[2])


@pytest.mark.parametrize("block", [1, 5, 1 << 20])
def test_single_row_without_line_end(tmp_path, monkeypatch, block):
    monkeypatch.setattr(tc, "BLOCK_BYTES", block)
    rec = read_recording(write(tmp_path, ["time_s,force_N", "2.5,-1e-300"], end=""))
    assert rec.n == 1 and rec.t0_s == 2.5 and rec.channels["force_N"].tolist() == [-1e-300]


def test_spaces_around_fields_and_unicode_space_at_line_ends_are_accepted(tmp_path, monkeypatch):
    monkeypatch.setattr(tc, "BLOCK_BYTES", 16)  # the spaces fall at chunk ends too
    cols = columns(40)
    lines = [" " + line.replace(",", " ,\t") + "\u00a0 " for line in lines_of(cols)[1:]]
    rec = read_recording(write(tmp_path, ["time_s, current_A ,force_N"] + lines))
    assert bit_equal(rec.channels["force_N"], cols[2]) and rec.n == 40


def test_channels_are_contiguous_float64_without_the_text(tmp_path):
    rec = read_recording(write(tmp_path, lines_of(columns(100))))
    for x in rec.channels.values():
        assert x.dtype == np.float64 and x.flags.c_contiguous and x.shape == (100,)


# --- every error at its line, wherever the chunks are cut -----------------------------------

N_ROWS = 30


def defect(kind: str, lines: list[str], i: int) -> tuple[list[str], str]:
    """Lines with a defect on file line ``i + 1`` (``lines[i]``), and the message it must give."""
    out = list(lines)
    fields = out[i].split(",")
    if kind == "not_a_number":
        fields[2] = "1.5x"
        msg = f":{i + 1}: column 3 (force_N): not a number: '1.5x'"
    elif kind == "empty_field":
        fields[1] = " "
        msg = f":{i + 1}: column 2 (current_A): empty field"
    elif kind == "too_few":
        fields = fields[:2]
        msg = f":{i + 1}: 2 fields, the header has 3"
    elif kind == "too_many":
        fields.append("0")
        msg = f":{i + 1}: 4 fields, the header has 3"
    elif kind == "not_finite":
        fields[2] = "-inf"
        msg = f":{i + 1}: column 3 (force_N): '-inf' is not a finite number"
    elif kind == "repeated_time":
        fields[0] = out[i - 1].split(",")[0]
        msg = f":{i + 1}: time_s does not increase"
    elif kind in ("blank_line", "space_line"):
        out.insert(i, "" if kind == "blank_line" else " \t ")
        return out, f":{i + 1}: empty line between samples"
    out[i] = ",".join(fields)
    return out, msg


KINDS = ["not_a_number", "empty_field", "too_few", "too_many", "not_finite", "repeated_time",
         "blank_line", "space_line"]


@pytest.mark.parametrize("block", [7, 64, 1 << 20])
@pytest.mark.parametrize("eol", ["\n", "\r\n"])
@pytest.mark.parametrize("kind", KINDS)
def test_a_defect_on_any_line_names_that_line(tmp_path, monkeypatch, kind, eol, block):
    monkeypatch.setattr(tc, "BLOCK_BYTES", block)
    clean = lines_of(columns(N_ROWS))
    for i in range(2 if kind == "repeated_time" else 1, N_ROWS + 1):
        lines, msg = defect(kind, clean, i)
        with pytest.raises(RecordingError) as info:
            read_recording(write(tmp_path, lines, eol=eol))
        assert str(info.value).startswith(str(tmp_path / "rec.csv") + msg), (i, str(info.value))


@pytest.mark.parametrize("block", [3, 50, 1 << 20])
def test_invalid_utf8_on_any_line_names_that_line_and_byte(tmp_path, monkeypatch, block):
    monkeypatch.setattr(tc, "BLOCK_BYTES", block)
    text = "\r\n".join(lines_of(columns(N_ROWS))).encode()
    starts = [0] + [k + 2 for k in range(len(text)) if text[k:k + 2] == b"\r\n"]
    for line, start in enumerate(starts[1:], start=2):
        raw = text[:start + 1] + b"\xff" + text[start + 2:]
        with pytest.raises(RecordingError) as info:
            read_recording(write(tmp_path, [], raw=raw))
        assert str(info.value) == f"{tmp_path / 'rec.csv'}:{line}: not UTF-8 (byte {start + 1})"


def test_trailing_blank_lines_are_not_samples_but_a_sample_after_them_is_an_error(tmp_path, monkeypatch):
    monkeypatch.setattr(tc, "BLOCK_BYTES", 4)  # the blank lines fill whole chunks
    lines = lines_of(columns(5))
    assert read_recording(write(tmp_path, lines + ["", "  ", "", ""])).n == 5
    with pytest.raises(RecordingError, match=r"rec\.csv:7: empty line between samples"):
        read_recording(write(tmp_path, lines + ["", "  ", "", "", lines[1]]))


def test_defects_at_the_default_chunk_boundary_of_a_large_file(tmp_path):
    """A ~3 MB file crosses the 1 MiB blocks twice; defects on the last line of a chunk and the
    first of the next are named at their own lines."""
    clean = lines_of(columns(70_000, seed=3))
    stem = write(tmp_path, clean)
    with open(tmp_path / "rec.csv", "rb") as fh:
        starts = [first for first, _ in tc.text_chunks(fh, "rec.csv")]
    assert len(starts) >= 3  # the file really is cut
    rec = read_recording(stem)
    assert rec.n == 70_000 and bit_equal(rec.channels["current_A"], columns(70_000, seed=3)[1])
    for first in starts[1:3]:
        for line in (first - 1, first):
            for kind in ("not_a_number", "too_few", "not_finite", "blank_line"):
                lines, msg = defect(kind, clean, line - 1)
                with pytest.raises(RecordingError) as info:
                    read_recording(write(tmp_path, lines))
                assert str(info.value).startswith(str(tmp_path / "rec.csv") + msg), (line, str(info.value))


# --- bounded memory -------------------------------------------------------------------------

def test_memory_is_the_arrays_plus_a_few_blocks_not_a_multiple_of_the_text(tmp_path, monkeypatch):
    """Peak traced allocation while reading: the float64 columns plus a bounded number of blocks,
    less than the text itself (the reader before issue 10 held several copies of the text)."""
    block = 1 << 16
    monkeypatch.setattr(tc, "BLOCK_BYTES", block)
    n = 60_000
    rng = np.random.default_rng(5)
    cols = np.vstack([np.arange(n) / FS] + [rng.standard_normal(n) for _ in range(5)])
    names = ["time_s", "current_A", "force_N", "flux_Wb", "sense_V", "command_V"]
    stem = write(tmp_path, lines_of(cols, names))
    text_bytes = (tmp_path / "rec.csv").stat().st_size
    arrays = cols.nbytes
    bound = arrays + 24 * block
    assert text_bytes > bound
    tracemalloc.start()
    try:
        rec = read_recording(stem)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert rec.n == n and bit_equal(rec.channels["command_V"], cols[5])
    assert peak < bound, f"peak {peak / 2**20:.1f} MiB for {arrays / 2**20:.1f} MiB of samples"
