"""``recover`` after damage in the middle of a log (issue 26, part 5): it resynchronises on the next
valid record, keeps every whole chunk before and after the damage, and says what it skipped; a
file that is not MCAP, or holds nothing whole, is an error and leaves no log behind.

Expected messages come from the undamaged log, read with mcap's reference reader and split by
its own chunk index, never from ``recover``; the recovered log is read back the same way.
"""

from __future__ import annotations

import io
import json
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from mcap.data_stream import ReadDataStream
from mcap.reader import make_reader
from mcap.records import Chunk, Message
from mcap.stream_reader import breakup_chunk

from hystbench.acquisition.sources import operating_meta
from hystbench.blocks import SampleBlock
from hystbench.cli.main import main as cli_main
from hystbench.errors import RecordingError
from hystbench.formats.mcaplog import ESTIMATE, STATUS, McapRecorder, log_metadata, recover
from hystbench.formats.mcaplog.resync import Source, next_valid_record

FS = 100_000.0
META = {"rig": "ecore_pm", "frequency_Hz": 320.0, "sample_rate_Hz": FS, "current_pp_A": 1.4}


def write_log(path: Path, n_blocks: int, compression: str, chunk_size: int) -> None:
    """A log as the daemon writes one: raw blocks (noisy float32, so chunks stay big after
    compression), an estimate per block and a status message, all at explicit log times."""
    rng = np.random.default_rng(7)
    n = 1000
    with McapRecorder(path, metadata={"recording": META}, compression=compression, chunk_size=chunk_size,
                      epoch_ns=1_700_000_000_000_000_000) as rec:
        for k in range(n_blocks):
            t = (k * n + np.arange(n)) / FS
            ch = {"current_A": 0.7 * np.sin(2 * np.pi * 320 * t) + 1e-3 * rng.standard_normal(n),
                  "force_N": 175 + 45 * np.sin(2 * np.pi * 320 * t) + 1e-2 * rng.standard_normal(n)}
            rec.add_block(SampleBlock(k * n, FS, {c: x.astype(np.float32) for c, x in ch.items()},
                                      meta=operating_meta(320.0, 1.4, 0.0, True)))
            rec.add_message(ESTIMATE, {"first_index": k * n, "end_index": (k + 1) * n},
                            rec.index_time_ns((k + 1) * n, FS))
            if k % 10 == 0:
                rec.add_message(STATUS, {"t_ns": k, "level": "info", "event": f"block {k}"},
                                rec.index_time_ns(k * n, FS))


def reference_messages(path: Path) -> list[tuple[str, int, bytes]]:
    """(topic, log time, bytes) of every message, in file order, by mcap's reference reader."""
    with open(path, "rb") as fh:
        return [(c.topic, m.log_time, m.data)
                for _, c, m in make_reader(fh, validate_crcs=True).iter_messages(log_time_order=False)]


def chunk_table(path: Path) -> list[tuple[int, int, list[tuple[str, int, bytes]]]]:
    """(start, end, messages) of every chunk, from the log's own index, each chunk split by mcap."""
    data = path.read_bytes()
    with open(path, "rb") as fh:
        summary = make_reader(fh).get_summary()
    out = []
    for ci in sorted(summary.chunk_indexes, key=lambda c: c.chunk_start_offset):
        body = data[ci.chunk_start_offset + 9:ci.chunk_start_offset + ci.chunk_length]
        recs = breakup_chunk(Chunk.read(ReadDataStream(io.BytesIO(body))), validate_crc=True)
        msgs = [(summary.channels[r.channel_id].topic, r.log_time, r.data) for r in recs if isinstance(r, Message)]
        out.append((ci.chunk_start_offset, ci.chunk_start_offset + ci.chunk_length, msgs))
    return out


@pytest.fixture(scope="module", params=["zstd", "none"])
def log(request, tmp_path_factory) -> tuple[Path, bytes, list, list]:
    path = tmp_path_factory.mktemp(f"log-{request.param}") / "log.mcap"
    write_log(path, 120, request.param, chunk_size=96 * 1024)
    table = chunk_table(path)
    msgs = reference_messages(path)
    assert [m for _, _, ms in table for m in ms] == msgs  # the index covers every message, in order
    assert len(table) >= 8
    return path, path.read_bytes(), msgs, table


def damage_inside_chunk(data: bytes, table: list, frac: float, n: int = 64) -> tuple[int, int]:
    """Where ``n`` bytes at ``frac`` of the file land inside a chunk's compressed data (the part its
    CRC covers), and that chunk's number: the chunk holding ``frac``, or the next one."""
    at = int(frac * len(data))
    k = next(i for i, (start, end, _) in enumerate(table) if end - n > max(at, start + 60))
    start, end, _ = table[k]
    return min(max(at, start + 60), end - n), k


def damaged_copy(tmp_path: Path, data: bytes, spots: list[int], n: int = 64, seed: int = 26) -> Path:
    buf = bytearray(data)
    rng = np.random.default_rng(seed)
    for at in spots:
        buf[at:at + n] = rng.bytes(n)
    path = tmp_path / "damaged.mcap"
    path.write_bytes(bytes(buf))
    return path


def test_64_random_bytes_at_40_percent_lose_only_the_chunk_they_hit(log, tmp_path: Path, capsys) -> None:
    """Before: the walk stopped at the damaged chunk, so everything after it (60 % of the log) was
    dropped.  Now the chunks before and after it are salvaged, byte for byte."""
    path, data, msgs, table = log
    at, k = damage_inside_chunk(data, table, 0.40)
    src = damaged_copy(tmp_path, data, [at])
    rep = recover(src, tmp_path / "out.mcap")
    expected = [m for i, (_, _, ms) in enumerate(table) if i != k for m in ms]
    assert reference_messages(rep.out) == expected
    assert len(expected) == len(msgs) - len(table[k][2]) and any(t[0] > at for t in table[k + 1:])
    # what the report says, against the log's own index
    assert rep.chunks == len(table) - 1 and rep.messages == len(expected)
    assert (rep.chunks_lost, rep.messages_lost) == (1, len(table[k][2]))
    assert "statistics" in rep.lost_counted_from and not rep.complete
    (skip,) = rep.skipped
    assert (skip.start, skip.end) == (table[k][0], table[k + 1][0])  # the chunk and its message index
    assert "CRC" in skip.why or "zstd" in skip.why
    assert rep.bytes_salvaged == len(data) - (table[k + 1][0] - table[k][0])
    assert log_metadata(rep.out)["recording"] == META
    # the command line says the same in words, and in JSON
    assert cli_main(["recover", str(src), "--out", str(tmp_path / "cli.mcap")]) == 0
    out = capsys.readouterr().out
    assert f"skipped bytes {table[k][0]}-{table[k + 1][0]}" in out and f"{len(table[k][2])} messages" in out
    assert cli_main(["recover", str(src), "--out", str(tmp_path / "cli.mcap"), "--overwrite", "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["skipped"] == [{"start": skip.start, "end": skip.end, "bytes": skip.bytes, "why": skip.why}]
    assert d["messages"] == len(expected) and d["chunks_lost"] == 1


def test_damage_in_two_places_loses_two_chunks(log, tmp_path: Path) -> None:
    path, data, msgs, table = log
    (a, ka), (b, kb) = damage_inside_chunk(data, table, 0.25), damage_inside_chunk(data, table, 0.75)
    assert ka != kb
    rep = recover(damaged_copy(tmp_path, data, [a, b]), tmp_path / "out.mcap")
    assert reference_messages(rep.out) == [m for i, (_, _, ms) in enumerate(table) if i not in (ka, kb) for m in ms]
    assert [(s.start, s.end) for s in rep.skipped] == [(table[ka][0], table[ka + 1][0]), (table[kb][0], table[kb + 1][0])]
    assert rep.chunks_lost == 2 and rep.messages_lost == len(table[ka][2]) + len(table[kb][2])


def test_damage_to_the_first_chunk_keeps_the_rest_through_the_summarys_channels(log, tmp_path: Path) -> None:
    """The first chunk holds the schema and channel records; the summary repeats them."""
    path, data, msgs, table = log
    start, end, first = table[0]
    rep = recover(damaged_copy(tmp_path, data, [(start + end) // 2]), tmp_path / "out.mcap")
    assert reference_messages(rep.out) == msgs[len(first):]
    assert log_metadata(rep.out)["recording"] == META  # metadata records sit before the first chunk


def test_damaged_and_cut_short_counts_what_it_recognised(log, tmp_path: Path) -> None:
    """A killed writer's log that was also damaged: no statistics survive, so the report counts the
    damaged chunks it recognised (the one hit, the one cut) and cannot count messages."""
    path, data, msgs, table = log
    at, k = damage_inside_chunk(data, table, 0.40)
    cut_k = len(table) - 2
    cut = (table[cut_k][0] + table[cut_k][1]) // 2
    src = damaged_copy(tmp_path, data[:cut], [at])
    rep = recover(src, tmp_path / "out.mcap")
    assert reference_messages(rep.out) == [m for i, (_, _, ms) in enumerate(table[:cut_k]) if i != k for m in ms]
    assert rep.chunks_lost == 2 and rep.messages_lost is None and "at least" in rep.lost_counted_from
    assert rep.skipped[-1].end == cut and "runs past the end of the file" in rep.stopped


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(frac=st.floats(0.0, 1.0), n=st.integers(1, 300), seed=st.integers(0, 2**32 - 1))
def test_any_damage_keeps_every_chunk_it_does_not_touch(log, tmp_path: Path, frac: float, n: int, seed: int) -> None:
    """Random bytes anywhere after the magic: every message of a chunk the damage does not touch is
    salvaged, and nothing is salvaged that was not written, in the written order."""
    path, data, msgs, table = log
    at = 8 + int(frac * (len(data) - 8 - n))
    src = damaged_copy(tmp_path, data, [at], n=n, seed=seed)
    rep = recover(src, tmp_path / "out.mcap", overwrite=True)
    got = reference_messages(rep.out)
    untouched = [m for start, end, ms in table if end <= at or start >= at + n for m in ms]
    it = iter(got)
    assert all(m in it for m in untouched)  # in order
    it = iter(msgs)
    assert all(m in it for m in got)  # a subsequence of what was written


# --- files with nothing to salvage --------------------------------------------------------------

@pytest.mark.parametrize("make, why", [
    (lambda data: data[:100], "nothing to salvage"),  # the start of a real log: magic, header, part of a record
    (lambda data: np.random.default_rng(1).bytes(100), "not an MCAP file"),
    (lambda data: b"", "not an MCAP file"),
    (lambda data: data[:5], "not an MCAP file"),
    (lambda data: data[:8], "nothing to salvage"),
])
def test_a_file_with_nothing_whole_is_an_error_and_writes_no_log(log, tmp_path: Path, capsys, make, why) -> None:
    """Before: a 100-byte file 'recovered' with status 0 into an empty log."""
    _, data, _, _ = log
    src = tmp_path / "small.mcap"
    src.write_bytes(make(data))
    with pytest.raises(RecordingError, match=rf"^{src}: {why}"):
        recover(src, tmp_path / "out.mcap")
    assert not (tmp_path / "out.mcap").exists()
    assert cli_main(["recover", str(src)]) == 2
    err = capsys.readouterr().err
    assert f"{src}: {why}" in err and "Traceback" not in err
    assert not (tmp_path / "small-recovered.mcap").exists()
    assert list(tmp_path.iterdir()) == [src]  # no temporary left either


# --- the scan itself ----------------------------------------------------------------------------

def test_the_scan_finds_a_chunk_behind_a_megabyte_of_noise_and_nothing_in_noise(log, tmp_path: Path) -> None:
    """Noise (with chunk opcodes and zero runs sprinkled in) is skipped a window at a time, and the
    first whole chunk after it is found at its exact offset."""
    _, data, _, table = log
    start, end, _ = table[3]
    rng = np.random.default_rng(3)
    noise = bytearray(rng.bytes(1_500_000))
    for at in rng.integers(0, len(noise) - 20, 3000):
        noise[at] = 0x06
        noise[at + 1:at + 9] = b"\x10\x00\x00\x00\x00\x00\x00\x00"  # a length that fits
    f = tmp_path / "noise.bin"
    f.write_bytes(bytes(noise) + data[start:end])
    with open(f, "rb") as fh:
        found = next_valid_record(Source(fh, f.stat().st_size), 0)
        assert found.offset == len(noise) and found.record is not None and found.record.opcode == 0x06
    f.write_bytes(bytes(noise))
    with open(f, "rb") as fh:
        found = next_valid_record(Source(fh, len(noise)), 0)
    assert found.offset == len(noise) and found.record is None


@pytest.mark.parametrize("tail", ["a second log", "zeros"])
def test_bytes_after_the_footer_are_reported_not_called_complete(log, tmp_path: Path, tail: str) -> None:
    """A log with another appended (two copied with `cat`), or padding after it: recover said "the log
    was complete" and 0 bytes not salvaged while the second log's messages were dropped."""
    path = log[0]
    data = path.read_bytes()
    extra = data if tail == "a second log" else bytes(65536)
    bad = tmp_path / "joined.mcap"
    bad.write_bytes(data + extra)
    rep = recover(bad, tmp_path / "out.mcap")
    assert rep.messages == len(reference_messages(path))  # the first log whole
    assert [(s.start, s.end) for s in rep.skipped] == [(len(data), len(data) + len(extra))]
    assert "after the log's footer and closing magic" in rep.skipped[0].why
    assert rep.as_dict()["bytes_lost"] == len(extra)
    whole = recover(path, tmp_path / "whole.mcap")
    assert whole.complete and not whole.skipped and whole.as_dict()["bytes_lost"] == 0
