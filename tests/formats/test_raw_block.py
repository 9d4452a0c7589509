"""The one raw-block codec: both framings carry the whole block (meta included), the decoder reads
both, and a log written before the codec was one (``data/pre_issue11.mcap``) still reads and
replays to the estimates it recorded."""

from __future__ import annotations

import base64
import json
from dataclasses import asdict, replace
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hystbench.acquisition.pipeline import Pipeline
from hystbench.acquisition.stages import WindowEstimator
from hystbench.blocks import BlockFlags, SampleBlock
from hystbench.errors import RecordingError
from hystbench.analysis.log_recordings import read_mcap_segments
from hystbench.formats.mcaplog import ESTIMATE, RAW, McapRecorder, McapSource, iter_blocks, iter_log, log_metadata
from hystbench.formats.raw_block import decode, encode_binary, encode_json
from hystbench.messages import Estimate, OperatingPoint

OLD_LOG = Path(__file__).parent / "data" / "pre_issue11.mcap"

points = st.builds(OperatingPoint, st.floats(1.0, 5e3), st.floats(0.0, 10.0), st.floats(-2.0, 2.0), st.booleans(),
                   st.booleans(), st.integers(0, 10**6))
arrays = st.integers(0, 200).flatmap(lambda n: st.tuples(
    st.sampled_from([np.float32, np.float64]),
    st.lists(st.floats(allow_nan=True, allow_infinity=True, width=32), min_size=n, max_size=n),
    st.lists(st.floats(allow_nan=False, width=32), min_size=n, max_size=n)))


@settings(max_examples=60, deadline=None)
@given(arrays, st.integers(-10**12, 10**12), st.sampled_from(list(BlockFlags)), st.integers(0, 10**6), points)
def test_both_framings_carry_the_whole_block_and_decode_alike(arr, first, flags, gap, point) -> None:
    dtype, a, b = arr
    blk = SampleBlock(first, 51_200.0, {"current_A": np.array(a, dtype=dtype), "force_N": np.array(b, dtype=dtype)},
                      flags=flags, gap_samples=gap, meta=point.to_meta())
    binary, text = encode_binary(blk), encode_json(blk)
    # the documented layouts, read by hand: u32 header length + JSON header + the raw values ...
    h = int.from_bytes(binary[:4], "little")
    head = json.loads(binary[4:4 + h])
    assert head["channels"] == [{"name": c, "unit": u, "dtype": np.dtype(dtype).name}
                                for c, u in (("current_A", "A"), ("force_N", "N"))]
    assert binary[4 + h:] == blk.channels["current_A"].tobytes() + blk.channels["force_N"].tobytes()
    # ... and JSON with base64 data, as Foxglove reads it
    obj = json.loads(text)
    assert base64.b64decode(obj["channels"][1]["data"]) == blk.channels["force_N"].tobytes()
    for h_ in (head, obj):  # the same header in both
        assert (h_["first_index"], h_["n"], h_["fs_hz"], h_["flags"], h_["gap_samples"]) == \
            (first, blk.n, 51_200.0, int(flags), gap)
        assert OperatingPoint.from_meta(h_["meta"]) == point
    for data in (binary, text):
        back = decode(data)
        assert (back.first_index, back.fs_hz, back.flags, back.gap_samples) == (first, 51_200.0, flags, gap)
        assert OperatingPoint.from_meta(back.meta) == point and dict(back.meta) == point.to_meta()
        for name, x in blk.channels.items():
            assert back.channels[name].dtype == x.dtype and back.channels[name].tobytes() == x.tobytes()


def test_one_channel_of_a_block_in_the_binary_framing() -> None:
    blk = SampleBlock(7, 1000.0, {"current_A": np.arange(3.0), "flux_Wb": np.arange(3.0, dtype=np.float32)},
                      meta=OperatingPoint(80.0, 1.0).to_meta())
    back = decode(encode_binary(blk, ["flux_Wb"]))
    assert list(back.channels) == ["flux_Wb"] and back.channels["flux_Wb"].tolist() == [0.0, 1.0, 2.0]
    assert OperatingPoint.from_meta(back.meta) == OperatingPoint(80.0, 1.0)


@pytest.mark.parametrize("data", [b"", b"\x05\x00\x00\x00{}", b"\x02\x00\x00\x00{}",
                                  b'{"first_index": 0}', b"\x00" * 12, b"not json"])
def test_garbage_is_a_recording_error_naming_where(data) -> None:
    with pytest.raises(RecordingError, match="msg 7: not a hystbench.RawBlock"):
        decode(data, "msg 7")


def replayed(log: Path, out: Path | None = None) -> list[dict]:
    """The log through today's pipeline with the estimation settings it was recorded with (and,
    with ``out``, recorded again); the estimates as published."""
    src = McapSource(log)
    settings_ = {k: float(v) for k, v in log_metadata(log)["config"]["estimation"].items()}
    got: list[dict] = []

    def run(recorder=None) -> None:
        pipe = Pipeline(src, estimator=WindowEstimator(src.fs_hz, src.metadata(), **settings_), recorder=recorder,
                        dtype=src.dtype)
        pipe.listeners.append(lambda t, o: got.append(o) if t == ESTIMATE else None)
        pipe.start()
        assert pipe.join(60) and pipe.error is None

    if out is None:
        run()
    else:
        with McapRecorder(out, metadata={k: v for k, v in log_metadata(log).items() if k != "hystbench"}) as rec:
            run(rec)
    return got


def _current_and_flux(e: Estimate) -> dict:
    """What of an estimate comes of the current and flux alone (the force's delays left out), t_ns
    0 (a replay's log time is its own), as one flat mapping of name to value."""
    keep = ("hysteresis",)
    flat = {}
    for name, value in asdict(replace(e, t_ns=0)).items():
        if name == "outliers":  # channel -> sample indices, compared whole
            flat[name] = repr(sorted((k, list(v)) for k, v in value.items()))
        elif isinstance(value, dict):  # the four per-delay tables
            flat.update({f"{name}.{k}": value[k] for k in keep if k in value})
        else:
            flat[name] = value
    return flat


def test_a_log_written_before_the_one_codec_reads_and_replays_to_its_own_estimates(tmp_path: Path,
                                                                                   monkeypatch) -> None:
    """``pre_issue11.mcap`` was written by commit d078bcb (see data/make_pre_issue11_log.py): a
    simulated E-core at 160 Hz, then 320 Hz, then the output off, estimates spelled the old way
    (``nominal_frequency_Hz``, ``frequency_Hz``).  Today's code reads its blocks sample for sample
    (against the log's bytes decoded here, base64 and JSON, without the codec) and replays it to the
    estimates it recorded, on the sine fits' numpy path (the code that wrote it): to rounding (1e-12)
    what comes of the current and flux (frequency, hysteresis delay); the instrument and total delays
    within a tenth of their standard error, as the method now reads them off one fit per channel
    where that code fitted each pair again (aa81c54).  The compiled regressors (issue 14) give the
    same estimates to rounding."""
    from hystbench.analysis.estimation import _lsq

    monkeypatch.setattr(_lsq, "KERNEL", False)
    blocks = list(iter_blocks(OLD_LOG))
    points_ = [OperatingPoint.from_meta(b.meta) for b in blocks]
    # the commands given at blocks 8 and 16, applied from the next block on (table: one sine set)
    assert [(p.frequency_hz, p.table) for p in points_] == [(160.0, 0)] * 9 + [(320.0, 1)] * 15
    assert [p.output_on for p in points_] == [True] * 17 + [False] * 7
    assert all(b.first_index == a.end_index for a, b in zip(blocks, blocks[1:]))
    raw = [m.json() for m in iter_log(OLD_LOG, [RAW])]
    assert len(raw) == len(blocks)
    for msg, block in zip(raw, blocks):
        for ch in msg["channels"]:
            sent = np.frombuffer(base64.b64decode(ch["data"]), dtype={"float32": "<f4", "float64": "<f8"}[ch["dtype"]])
            assert block.channels[ch["name"]].tobytes() == sent.tobytes(), (msg["first_index"], ch["name"])
    old = [m.json() for m in iter_log(OLD_LOG, [ESTIMATE])]
    renamed = {"nominal_frequency_Hz": "nominal_frequency_hz", "current_pp_A": "current_pp_a",
               "frequency_Hz": "frequency_hz", "frequency_std_Hz": "frequency_std_hz"}
    recorded = [Estimate.from_json({renamed.get(k, k): v for k, v in e.items()}) for e in old]
    assert len(recorded) >= 10 and {e.nominal_frequency_hz for e in recorded} == {160.0, 320.0}
    numpy_path = [Estimate.from_json(e) for e in replayed(OLD_LOG)]
    for got in (numpy_path, [Estimate.from_json(e) for e in replayed(OLD_LOG, out=tmp_path / "again.mcap")]):
        # equal but for t_ns, the log time (a replay has its own clock, or none), and the two delays
        # read off the force's fit; the numbers to rounding, as another numpy or BLAS build sums in
        # another order (the last two digits of a float64); every other field, and which fields there are, exactly
        for e, want in zip(got, recorded, strict=True):
            a, b = _current_and_flux(e), _current_and_flux(want)
            assert a.keys() == b.keys()
            floats = [k for k, v in b.items() if isinstance(v, float)]
            assert {k: a[k] for k in floats} == pytest.approx({k: b[k] for k in floats}, rel=1e-12, abs=0.0)
            assert {k: v for k, v in a.items() if k not in floats} == {k: v for k, v in b.items() if k not in floats}
        for e, want in zip(got, recorded):
            for name in ("instrument", "total"):
                se = want.delays_std_s[name]
                assert e.delays_s[name] == pytest.approx(want.delays_s[name], abs=0.1 * se), (e.first_index, name)
                assert e.delays_std_s[name] == pytest.approx(se, rel=0.05), (e.first_index, name)
    again = list(iter_blocks(tmp_path / "again.mcap"))
    assert [(b.first_index, b.n, dict(b.meta)) for b in again] == [(b.first_index, b.n, dict(b.meta)) for b in blocks]
    monkeypatch.setattr(_lsq, "KERNEL", True)
    compiled = [Estimate.from_json(e) for e in replayed(OLD_LOG)]
    assert [(e.first_index, e.end_index) for e in compiled] == [(e.first_index, e.end_index) for e in numpy_path]
    for got, want in zip(compiled, numpy_path):
        assert got.frequency_hz == pytest.approx(want.frequency_hz, rel=1e-8, abs=1e-3 * want.frequency_std_hz)
        for name, delay in want.delays_s.items():
            assert got.delays_s[name] == pytest.approx(delay, rel=1e-8, abs=1e-3 * want.delays_std_s[name])
    # the segments, as interchange-format recordings: the sidecar spells the point the old way
    segs = read_mcap_segments(OLD_LOG, include_idle=True)
    assert [(r.frequency_hz, r.metadata.get("output_on", True)) for r in segs if not r.metadata.get("settling")] \
        == [(160.0, True), (320.0, True), (320.0, False)]
    assert log_metadata(OLD_LOG)["recording"]["rig"] == "ecore_pm"
