"""Reading hostile MCAP files (issue 26, part 5): a file that is not MCAP is named as such, and a
chunk can never make the reader or ``recover`` decompress more than it declares (capped by
MAX_RECORD_BYTES).  Memory is measured in a child process (its own peak RSS); no timing."""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
import zstandard
from mcap.data_stream import RecordBuilder
from mcap.records import Channel, Chunk, DataEnd, Footer, Header, Schema

from hystbench.cli.main import main as cli_main
from hystbench.errors import RecordingError
from hystbench.formats.mcaplog import iter_log, log_metadata, recover
from hystbench.formats.mcaplog.chunks import MAGIC, MAX_RECORD_BYTES, chunk_records

BOMB_BYTES = 48 << 20  # what the bomb's zstd frame holds: zeros, a few kB compressed


def _zeros_frame(n: int) -> bytes:
    """A zstd frame of ``n`` zero bytes that declares its size, built without holding them."""
    cctx = zstandard.ZstdCompressor()
    obj = cctx.compressobj(size=n)
    block = bytes(1 << 20)
    parts = [obj.compress(block) for _ in range(n // len(block))]
    return b"".join(parts) + obj.flush()


def _bomb_log(path: Path, declared: int) -> Path:
    """A finished MCAP file (magic, header, schema, channel, one chunk, data end, footer) whose chunk
    says it holds ``declared`` bytes but whose zstd frame unpacks to BOMB_BYTES."""
    b = RecordBuilder()
    Header(profile="hystbench", library="test").write(b)
    Schema(id=1, name="s", encoding="jsonschema", data=b"{}").write(b)
    Channel(id=1, schema_id=1, topic="/raw", message_encoding="json", metadata={}).write(b)
    Chunk(compression="zstd", data=_zeros_frame(BOMB_BYTES), message_start_time=0, message_end_time=0,
          uncompressed_crc=0, uncompressed_size=declared).write(b)
    DataEnd(data_section_crc=0).write(b)
    body = MAGIC + b.end()
    f = RecordBuilder()
    Footer(summary_start=len(body), summary_offset_start=0, summary_crc=0).write(f)  # an empty summary
    path.write_bytes(body + f.end() + MAGIC)
    return path


_PEAK = """
    import json, resource, sys
    from hystbench.errors import RecordingError
    from hystbench.formats.mcaplog import iter_log, recover
    def peak(): return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
    before = peak()
    try:
        if sys.argv[2] == "read":
            outcome = f"read {len(list(iter_log(sys.argv[1])))} messages"
        else:
            outcome = f"recovered {recover(sys.argv[1], sys.argv[1] + '.out').messages} messages"
    except Exception as err:
        outcome = (str(err) if isinstance(err, RecordingError) else repr(err))[:1000]
    print(json.dumps({"before": before, "after": peak(), "outcome": outcome}))
"""


@pytest.mark.parametrize("how", ["read", "recover"])
def test_a_chunk_that_unpacks_to_more_than_it_declares_is_refused_in_bounded_memory(tmp_path: Path, how) -> None:
    """Before: mcap's reader let zstandard unpack what the frame declared (48 MB for a chunk of
    1000 bytes, then split the zeros into 5 million empty records)."""
    log = _bomb_log(tmp_path / "bomb.mcap", declared=1000)
    assert log.stat().st_size < 64 << 10
    proc = subprocess.run([sys.executable, "-c", textwrap.dedent(_PEAK), str(log), how], capture_output=True,
                          text=True, timeout=300)  # a guard against a hang, not a timing
    assert proc.returncode == 0, proc.stderr
    got = json.loads(proc.stdout.strip().splitlines()[-1])
    assert got["after"] - got["before"] < 16 << 20, got
    if how == "read":
        assert got["outcome"].startswith(f"{log}: not a complete MCAP log"), got
        assert "chunk decompresses to more than 1000 bytes" in got["outcome"], got
    else:
        assert got["outcome"].startswith(f"{log}: nothing to salvage"), got


def test_a_chunk_declaring_more_than_max_record_bytes_is_not_decompressed() -> None:
    frame = zstandard.compress(b"x" * 100)
    chunk = Chunk(compression="zstd", data=frame, message_start_time=0, message_end_time=0,
                  uncompressed_crc=0, uncompressed_size=MAX_RECORD_BYTES + 1)
    with pytest.raises(RecordingError, match="over MAX_RECORD_BYTES"):
        chunk_records(chunk)
    short = Chunk(compression="zstd", data=frame, message_start_time=0, message_end_time=0,
                  uncompressed_crc=0, uncompressed_size=200)
    with pytest.raises(RecordingError, match="decompresses to 100 bytes, its header says 200"):
        chunk_records(short)


@pytest.mark.parametrize("content", [b"", b"\x89MCA", np.random.default_rng(5).bytes(100), b"time_s,force_N\n0,1\n"])
def test_a_file_that_is_not_mcap_is_named_so_by_every_reader(tmp_path: Path, capsys, content: bytes) -> None:
    """Before: 'not a complete MCAP log (InvalidMagic ...); if the writer was killed, `hystbench
    recover` salvages its complete chunks', a pointer that could not help."""
    path = tmp_path / "x.mcap"
    path.write_bytes(content)
    for read in (lambda: list(iter_log(path)), lambda: log_metadata(path), lambda: recover(path)):
        with pytest.raises(RecordingError, match=rf"^{path}: not an MCAP file \(bad magic") as err:
            read()
        assert "recover" not in str(err.value)
    assert cli_main(["estimate", str(path)]) == 2
    out = capsys.readouterr().err
    assert f"{path}: not an MCAP file" in out and "Traceback" not in out and out.count("\n") == 1
