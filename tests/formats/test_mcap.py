"""MCAP logs: the raw-block codec, the recorder's life cycle and rotation, reading a log as
recordings, export, and recovery of a cut-off log at any byte."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from mcap.reader import make_reader

from hystbench.cli.main import main as pipeline_main
from hystbench.analysis.log_recordings import read_mcap_recording, read_mcap_segments
from hystbench.formats.mcaplog import (ESTIMATE, RAW, STATUS, TOPICS, McapRecorder, iter_blocks, iter_log,
                                       log_metadata, McapSource, recover)
from hystbench.formats.raw_block import decode, encode_json
from hystbench.formats.recording import read_recording
from hystbench.acquisition.sources import operating_meta
from hystbench.blocks import BlockFlags, SampleBlock
from hystbench.errors import RecordingError

FS = 10_000.0
META = {"rig": "ecore_pm", "frequency_Hz": 320.0, "sample_rate_Hz": FS, "current_pp_A": 1.4, "operator": "tests"}


def blocks(n_blocks: int, n: int = 500, *, freq: float = 320.0, start: int = 0, dtype=np.float32) -> list[SampleBlock]:
    rng = np.random.default_rng(start)
    out = []
    for k in range(n_blocks):
        i0 = start + k * n
        t = (i0 + np.arange(n)) / FS
        ch = {"current_A": 0.7 * np.sin(2 * np.pi * freq * t), "force_N": 175 + 45 * np.sin(2 * np.pi * freq * t - 0.05),
              "flux_Wb": 5e-5 * np.sin(2 * np.pi * freq * t - 0.02) + 1e-8 * rng.standard_normal(n)}
        out.append(SampleBlock(i0, FS, {c: x.astype(dtype) for c, x in ch.items()},
                               meta=operating_meta(freq, 1.4, 0.0, True)))
    return out


def write_log(path: Path, bl: list[SampleBlock], **kw) -> McapRecorder:
    with McapRecorder(path, metadata={"recording": META, "config": {"x": 1}}, **kw) as rec:
        for b in bl:
            rec.add_block(b)
            rec.add_message(ESTIMATE, {"first_index": b.first_index, "end_index": b.end_index, "t_ns": 0,
                                       "delays_s": {"hysteresis": float("nan")}})
        rec.add_message(STATUS, {"t_ns": 1, "level": "info", "event": "done"})
    return rec


arrays = st.integers(0, 300).flatmap(lambda n: st.tuples(
    st.sampled_from([np.float32, np.float64]),
    st.lists(st.floats(allow_nan=True, allow_infinity=True, width=32), min_size=n, max_size=n),
    st.lists(st.floats(allow_nan=False, width=32), min_size=n, max_size=n)))


@settings(max_examples=60, deadline=None)
@given(arrays, st.integers(-10**12, 10**12), st.sampled_from(list(BlockFlags)), st.integers(0, 10**6),
       st.dictionaries(st.sampled_from(["frequency_hz", "output_on", "skew_s.force_N"]), st.floats(-1e6, 1e6)))
def test_raw_block_codec_round_trip_is_exact(arr, first, flags, gap, meta) -> None:
    dtype, a, b = arr
    blk = SampleBlock(first, 51_200.0, {"current_A": np.array(a, dtype=dtype), "force_N": np.array(b, dtype=dtype)},
                      flags=flags, gap_samples=gap, meta=meta)
    data = encode_json(blk)
    obj = json.loads(data)  # plain JSON, as Foxglove reads it
    assert [c["unit"] for c in obj["channels"]] == ["A", "N"]
    back = decode(data)
    assert (back.first_index, back.fs_hz, back.flags, back.gap_samples, dict(back.meta)) == \
        (first, 51_200.0, flags, gap, meta)
    for name in blk.channels:
        assert back.channels[name].dtype == blk.channels[name].dtype
        assert back.channels[name].tobytes() == blk.channels[name].tobytes()


def test_decode_refuses_garbage_naming_where() -> None:
    with pytest.raises(RecordingError, match="msg 7: not a hystbench.RawBlock"):
        decode(b'{"first_index": 0}', "msg 7")


@pytest.mark.parametrize("edit, words", [
    (("51200.0", "NaN"), "fs_hz must be a sample rate in (0, 1e+12] Hz, got nan"),  # JSON's NaN parses
    (("51200.0", "Infinity"), "got inf"),
    (("51200.0", "1e308"), "got 1e+308"),  # a replay's count of samples overflowed
    (('"meta": {"frequency_hz": 320.0', '"meta": {"frequency_hz": NaN'), "meta frequency_hz = nan"),
    (('"meta": {"frequency_hz": 320.0', '"meta": {"frequency_hz": 1' + "0" * 400), "OverflowError"),
    (('"gap_samples": 0', '"gap_samples": -3'), "gap_samples must be >= 0"),
])
def test_a_block_header_no_writer_makes_is_refused_naming_the_message(edit, words) -> None:
    """Each was a traceback in replay, export or estimate (ValueError, OverflowError, ZeroDivisionError)."""
    text = encode_json(blocks(1, 100)[0]).decode().replace("10000.0", "51200.0", 1)
    assert edit[0] in text
    with pytest.raises(RecordingError, match="raw message 3: not a hystbench.RawBlock") as err:
        decode(text.replace(*edit, 1).encode(), "raw message 3")
    assert words in str(err.value), str(err.value)


def test_a_block_without_channels_is_refused() -> None:
    with pytest.raises(RecordingError, match="no channels"):  # a replay took its channels from it: StopIteration
        decode(b'{"first_index": 0, "n": 0, "fs_hz": 1000.0, "flags": 0, "gap_samples": 0, "channels": []}', "m")


@pytest.mark.parametrize("setting, words", [
    ({"settle_s": "x"}, "estimation.settle_s must be a number in [0, 1e9], got 'x'"),
    ({"settle_s": 1e308}, "estimation.settle_s must be a number in [0, 1e9]"),
    ({"max_fs_hz": 0}, "estimation.max_fs_hz must be a number in (0, 1e9], got 0"),  # a division by zero
    ({"periods": 1}, "estimation.periods must be a number in [2, 1e9], got 1"),
])
def test_a_logs_estimation_settings_are_checked_by_every_reader(tmp_path: Path, setting, words) -> None:
    """replay estimates with them, export and estimate skip the settling by them: a bad one was a
    traceback in one and a quiet default in another."""
    log = tmp_path / "cfg.mcap"
    with McapRecorder(log, metadata={"recording": META, "config": {"estimation": setting}}) as rec:
        for b in blocks(4):
            rec.add_block(b)
    for read in (read_mcap_segments, McapSource):
        with pytest.raises(RecordingError, match=r"cfg\.mcap: metadata record 'config': ") as err:
            read(log)
        assert words in str(err.value), str(err.value)


def test_a_metadata_record_that_is_no_object_is_refused_naming_it(tmp_path: Path) -> None:
    from mcap.writer import Writer

    log = tmp_path / "list.mcap"
    with open(log, "wb") as fh:
        w = Writer(fh)
        w.start()
        w.add_metadata("recording", {"json": "[1, 2]"})
        w.finish()
    with pytest.raises(RecordingError, match=r"list\.mcap: metadata record 'recording' must be a JSON object, got list"):
        log_metadata(log)


def test_recorder_life_cycle_schemas_and_metadata(tmp_path: Path) -> None:
    bl = blocks(12)
    rec = write_log(tmp_path / "a.mcap", bl, chunk_size=16_000)
    assert rec.paths == [tmp_path / "a.mcap"]
    with open(tmp_path / "a.mcap", "rb") as fh:
        reader = make_reader(fh)
        summary = reader.get_summary()
        assert reader.get_header().profile == "hystbench"
        topics = {c.topic: c for c in summary.channels.values()}
        assert set(topics) == set(TOPICS)
        for c in topics.values():  # every message is JSON with a JSON schema: Foxglove decodes it
            assert c.message_encoding == "json"
            schema = summary.schemas[c.schema_id]
            assert schema.encoding == "jsonschema" and json.loads(schema.data)["type"] == "object"
        assert summary.statistics.channel_message_counts[topics[RAW].id] == 12
        assert summary.statistics.chunk_count >= 2  # small chunks
    got = list(iter_blocks(tmp_path / "a.mcap"))
    assert [b.first_index for b in got] == [b.first_index for b in bl]
    for a, b in zip(got, bl):
        for c in a.channels:
            np.testing.assert_array_equal(a.channels[c], b.channels[c])
        assert a.meta == b.meta
    meta = log_metadata(tmp_path / "a.mcap")
    assert meta["recording"] == META and meta["config"] == {"x": 1}
    assert meta["hystbench"]["software"].startswith("hystbench ")
    est = [m.json() for m in iter_log(tmp_path / "a.mcap", [ESTIMATE])]
    assert est[0]["delays_s"]["hysteresis"] is None  # NaN is not JSON: written as null
    with pytest.raises(RecordingError, match="already exists"):
        McapRecorder(tmp_path / "a.mcap").start()
    with pytest.raises(RecordingError, match="not started"):
        McapRecorder(tmp_path / "b.mcap").add_block(bl[0])


def test_rotation_by_size_and_by_time(tmp_path: Path) -> None:
    bl = blocks(40)
    rec = write_log(tmp_path / "s.mcap", bl, rotate_bytes=30_000, chunk_size=8_000)
    assert len(rec.paths) >= 3 and all(p.name.startswith("s-") for p in rec.paths)
    got = [b for p in rec.paths for b in iter_blocks(p)]
    assert [b.first_index for b in got] == [b.first_index for b in bl]  # nothing lost between parts
    for p in rec.paths:  # each part stands alone
        assert log_metadata(p)["recording"] == META
    assert log_metadata(rec.paths[1])["hystbench"]["previous_part"] == rec.paths[0].name
    import time

    with McapRecorder(tmp_path / "t.mcap", metadata={"recording": META}, rotate_s=0.05) as r2:
        for b in bl[:4]:
            r2.add_block(b)
            time.sleep(0.06)
    assert len(r2.paths) == 4


def test_the_size_of_a_log_whose_finished_part_was_deleted_is_what_is_left(tmp_path: Path, monkeypatch) -> None:
    """Retention deletes a finished part while the stats ask the log's size (another thread): the part
    that went counts 0; it raised FileNotFoundError, which took the whole pipeline down (found beside two
    busy loops, the delete falling between an exists() and a stat()).  The race made deterministic: every
    path says it exists, and the deleted one is gone when its size is read."""
    monkeypatch.setattr(Path, "exists", lambda self: True)
    with McapRecorder(tmp_path / "r.mcap", metadata={"recording": META}, rotate_bytes=30_000,
                      chunk_size=8_000) as rec:
        for b in blocks(40):
            rec.add_block(b)
            if len(rec.paths) >= 3:
                break
        gone, kept = rec.paths[0], rec.paths[1:-1]
        gone.unlink()
        assert rec.bytes_written == sum(p.stat().st_size for p in kept) + rec._fh.tell()


#: The frame's ring-down after a change: 10 time constants of the paper's load cell + frame
#: (fn 4450 Hz, zeta 0.012: tau = 1 / (zeta 2 pi fn)), in samples at FS
SETTLE = math.ceil(10 / (0.012 * 2 * math.pi * 4450.0) * FS)


def test_log_as_recordings_segments_and_export(tmp_path: Path) -> None:
    idle = [SampleBlock(b.first_index, FS, b.channels, meta=operating_meta(320.0, 1.4, 0.0, False)) for b in blocks(2)]
    seg_a = blocks(4, freq=320.0, start=1000)
    seg_b = blocks(4, freq=160.0, start=3000)
    seg_c = blocks(4, freq=160.0, start=6000)  # a gap after seg_b: a separate segment
    for b in seg_b:
        b.meta["frequency_hz"] = 160.0
    for b in seg_c:
        b.meta["frequency_hz"] = 160.0
    log = tmp_path / "sweep.mcap"
    write_log(log, idle + seg_a + seg_b + seg_c)
    recs = read_mcap_segments(log)  # each starts after the bench settled from its change (or gap)
    assert [(r.frequency_hz, r.n, round(r.t0_s * FS)) for r in recs] == [
        (320.0, 2000 - SETTLE, 1000 + SETTLE), (160.0, 2000 - SETTLE, 3000 + SETTLE), (160.0, 2000 - SETTLE, 6000 + SETTLE)]
    every = read_mcap_segments(log, include_idle=True)  # nothing lost: the settling is there too
    assert [(round(r.t0_s * FS), r.n) for r in every] == [
        (0, 1000), (1000, SETTLE), (1000 + SETTLE, 2000 - SETTLE), (3000, SETTLE), (3000 + SETTLE, 2000 - SETTLE),
        (6000, SETTLE), (6000 + SETTLE, 2000 - SETTLE)]
    assert [r.metadata.get("settling", False) for r in every] == [False, True, False, True, False, True, False]
    # issue 16: the idle segment says what the blocks carried: output off, no current
    assert every[0].metadata["output_on"] is False and every[0].current_pp_a == 0.0
    assert every[0].metadata["generator_current_pp_A"] == 1.4
    assert all("output_on" not in r.metadata and r.current_pp_a == 1.4 for r in every[1:])
    with pytest.raises(RecordingError, match="3 segments"):
        read_mcap_recording(log)
    one = read_mcap_recording(log, segment=1)
    np.testing.assert_array_equal(one.channels["force_N"][:500 - SETTLE], seg_b[0].channels["force_N"][SETTLE:])
    assert one.metadata["operator"] == "tests" and one.metadata["mcap_source"]["first_index"] == 3000 + SETTLE
    # export: one interchange-format recording per segment, lossless, metadata kept
    out = tmp_path / "exported"
    assert pipeline_main(["export", str(log), "--out", str(out)]) == 0
    files = sorted(p.name for p in out.glob("*.csv"))
    assert files == ["ecore_pm_160Hz_1.4App.csv", "ecore_pm_160Hz_1.4App_seg2.csv", "ecore_pm_320Hz_1.4App.csv"]
    back = read_recording(out / "ecore_pm_160Hz_1.4App")
    for c in one.channels:
        np.testing.assert_array_equal(back.channels[c], one.channels[c])
    assert back.metadata["operator"] == "tests" and back.t0_s == one.t0_s
    assert pipeline_main(["export", str(log), "--out", str(out)]) == 2  # no silent overwrite
    # with the idle segments: the output-off one's sidecar says so (it claimed 1.4 A-pp before)
    out2 = tmp_path / "all"
    assert pipeline_main(["export", str(log), "--out", str(out2), "--include-idle"]) == 0
    off = json.loads((out2 / "ecore_pm_320Hz_0App_off.json").read_text())
    assert off["output_on"] is False and off["current_pp_A"] == 0.0
    assert len(list(out2.glob("*_settling*.csv"))) == 3


def _messages(path: Path) -> list[tuple[str, int, bytes]]:
    return [(m.topic, m.log_time_ns, m.data) for m in iter_log(path)]


@pytest.fixture(scope="module")
def finished_log(tmp_path_factory) -> tuple[Path, bytes, list, list[tuple[int, int]]]:
    """A log with many small chunks, its bytes, its messages, and per chunk (end offset, messages)."""
    import io

    from mcap.data_stream import ReadDataStream
    from mcap.records import Chunk, Message
    from mcap.stream_reader import breakup_chunk

    path = tmp_path_factory.mktemp("cut") / "full.mcap"
    write_log(path, blocks(30, n=300), chunk_size=4_000)
    data = path.read_bytes()
    with open(path, "rb") as fh:
        idx = make_reader(fh).get_summary().chunk_indexes
    chunks = []
    for ci in sorted(idx, key=lambda c: c.chunk_start_offset):
        body = data[ci.chunk_start_offset + 9: ci.chunk_start_offset + ci.chunk_length]
        recs = breakup_chunk(Chunk.read(ReadDataStream(io.BytesIO(body))))
        chunks.append((ci.chunk_start_offset + ci.chunk_length, sum(isinstance(r, Message) for r in recs)))
    return path, data, _messages(path), chunks


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(frac=st.floats(0.0, 1.0))
def test_recover_any_cut_keeps_every_complete_chunk(finished_log, tmp_path: Path, frac: float) -> None:
    """Cut the file at any byte: the recovered log holds exactly the messages of the chunks that
    are whole before the cut, byte for byte and in order, and nothing else; a cut before the first
    whole chunk leaves nothing to salvage, which is an error, not an empty log."""
    path, data, msgs, chunks = finished_log
    cut = max(8, int(frac * len(data)))
    src = tmp_path / f"cut-{cut}.mcap"
    src.write_bytes(data[:cut])
    whole = sum(n for end, n in chunks if end <= cut)
    if whole == 0:
        with pytest.raises(RecordingError, match=rf"^{src}: nothing to salvage"):
            recover(src, tmp_path / f"rec-{cut}.mcap", overwrite=True)
        assert not (tmp_path / f"rec-{cut}.mcap").exists()
        return
    rep = recover(src, tmp_path / f"rec-{cut}.mcap", overwrite=True)
    got = _messages(rep.out)
    assert got == msgs[:whole]
    if cut == len(data):
        assert rep.complete
    if rep.complete:  # the data section was whole (only the summary may have been cut)
        assert got == msgs
    if cut >= chunks[0][0]:
        assert log_metadata(rep.out)["recording"] == META


def test_unfinished_log_is_refused_with_a_pointer_to_recover(finished_log, tmp_path: Path) -> None:
    _, data, _, _ = finished_log
    (tmp_path / "cut.mcap").write_bytes(data[: len(data) // 2])
    with pytest.raises(RecordingError, match="hystbench recover"):
        list(iter_blocks(tmp_path / "cut.mcap"))
    assert pipeline_main(["recover", str(tmp_path / "cut.mcap")]) == 0
    assert (tmp_path / "cut-recovered.mcap").exists()
    assert pipeline_main(["recover", str(tmp_path / "cut.mcap")]) == 2  # refuses to overwrite
    (tmp_path / "junk.mcap").write_bytes(b"not an mcap file at all")
    with pytest.raises(RecordingError, match="bad magic"):
        recover(tmp_path / "junk.mcap")


def _conforms(value, schema: dict) -> bool:
    """``value`` is of the JSON schema's type (the subset the log's schemas use), all the way down."""
    types = schema["type"] if isinstance(schema["type"], list) else [schema["type"]]
    checks = {"null": lambda v: v is None, "boolean": lambda v: isinstance(v, bool),
              "integer": lambda v: isinstance(v, int) and not isinstance(v, bool),
              "number": lambda v: isinstance(v, (int, float)) and not isinstance(v, bool),
              "string": lambda v: isinstance(v, str),
              "array": lambda v: isinstance(v, list) and all(_conforms(x, schema["items"]) for x in v),
              "object": lambda v: isinstance(v, dict) and all(_conforms(x, schema["additionalProperties"])
                                                              for x in v.values())}
    return any(checks[t](value) for t in types)


def test_the_estimate_schema_in_a_log_is_exactly_the_estimate_type(tmp_path: Path) -> None:
    """The JSON schema a log registers for /estimate names every field of ``Estimate`` and nothing
    else, with the fields' types: every estimate the pipeline logged conforms to it, key for key,
    and reads back as an ``Estimate`` that writes the same JSON."""
    from dataclasses import fields

    from hystbench.acquisition.pipeline import Pipeline
    from hystbench.acquisition.sources import SyntheticSource
    from hystbench.acquisition.stages import WindowEstimator
    from hystbench.messages import Estimate

    src = SyntheticSource(fs_hz=20_000.0, block_samples=500, pace="max", duration_s=0.3, noise=1e-3, seed=1)
    with McapRecorder(tmp_path / "e.mcap", metadata={"recording": src.metadata()}) as rec:
        pipe = Pipeline(src, estimator=WindowEstimator(src.fs_hz, src.metadata(), periods=4.0, min_hop_s=0.0),
                        recorder=rec).start()
        assert pipe.join(60) and pipe.error is None
    with open(tmp_path / "e.mcap", "rb") as fh:
        summary = make_reader(fh).get_summary()
    (channel,) = [c for c in summary.channels.values() if c.topic == ESTIMATE]
    schema = json.loads(summary.schemas[channel.schema_id].data)
    assert summary.schemas[channel.schema_id].name == schema["title"] == "hystbench.Estimate"
    assert list(schema["properties"]) == [f.name for f in fields(Estimate)]
    logged = [m.json() for m in iter_log(tmp_path / "e.mcap", [ESTIMATE])]
    assert len(logged) >= 5 and not any(e["error"] for e in logged)
    for e in logged:
        assert set(e) == set(schema["properties"]) and set(schema["required"]) <= set(e)
        assert all(_conforms(e[k], p) for k, p in schema["properties"].items()), e
        assert json.loads(json.dumps(Estimate.from_json(e).to_json())) == e
        assert e["harmonic"] == 1 and abs(e["delays_s"]["hysteresis"] - 10e-6) < 0.5e-6  # the synthetic flux lag


def test_a_block_s_point_survives_the_log(tmp_path: Path) -> None:
    """The typed point is the meta's reading: what a log hands back is the point each block was
    recorded with (settling, table and output off included), and no point where a block had none."""
    from hystbench.messages import OperatingPoint

    played = [OperatingPoint(320.0, 1.4), OperatingPoint(160.0, 0.8, offset_a=0.1, settling=True, table=2),
              OperatingPoint(160.0, 0.8, output_on=False, table=2)]
    bl = [SampleBlock(b.first_index, FS, b.channels, meta=p.to_meta()) for b, p in zip(blocks(3), played)]
    bl.append(SampleBlock(1500, FS, blocks(1, start=1500)[0].channels, meta={"skew_s.force_N": 2e-6}))
    log = tmp_path / "points.mcap"
    with McapRecorder(log, metadata={"recording": META}, idle_raw="full") as rec:
        for b in bl:
            rec.add_block(b)
    back = list(iter_blocks(log))
    assert [b.point for b in back] == [*played, None]
    assert [dict(b.meta) for b in back] == [dict(b.meta) for b in bl]  # the wire form is the meta, unchanged
    with McapRecorder(tmp_path / "active.mcap", metadata={"recording": META}, idle_raw="off") as rec:
        for b in bl:
            rec.add_block(b)
    kept = list(iter_blocks(tmp_path / "active.mcap"))  # output off is dropped; no point is taken as on
    assert [b.point for b in kept] == [played[0], played[1], None]
