"""Frame codec, COBS and both deframers: round trips, resynchronisation after arbitrary damage,
and exact sample accounting (property tests)."""

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hystbench.drivers.protocols.framing import (
    MAX_FRAME_SIZE, OVERHEAD, CobsDeframer, Frame, FrameError, LengthPrefixDeframer, cobs_decode,
    cobs_decode_reference, cobs_encode, cobs_encode_reference, cobs_record, decode_frame, encode_frame,
    frames_from_block, length_prefixed)

FAST = settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])


@st.composite
def frames(draw, max_channels=3, max_samples=40):
    c = draw(st.integers(1, max_channels))
    n = draw(st.integers(0, max_samples))
    bits = draw(st.lists(st.integers(0, 2**32 - 1), min_size=c * n, max_size=c * n))
    samples = np.array(bits, dtype=np.uint32).view(np.float32).reshape(c, n)  # any bit pattern, NaNs too
    return Frame(draw(st.integers(0, 255)), draw(st.integers(0, 2**32 - 1)),
                 draw(st.integers(-2**62, 2**62)), samples, draw(st.integers(0, 0xFFFF)))


def same(a: Frame, b: Frame) -> bool:
    return (a.stream_id, a.seq, a.first_index, a.flags) == (b.stream_id, b.seq, b.first_index, b.flags) and \
        a.samples.shape == b.samples.shape and a.samples.tobytes() == b.samples.tobytes()


@FAST
@given(frames())
def test_frame_round_trip_is_bit_exact(frame):
    raw = encode_frame(frame)
    assert len(raw) == OVERHEAD + frame.samples.nbytes
    assert same(decode_frame(raw), frame)


@FAST
@given(frames(), st.data())
def test_any_single_byte_change_is_detected(frame, data):
    raw = bytearray(encode_frame(frame))
    i = data.draw(st.integers(0, len(raw) - 1))
    raw[i] ^= data.draw(st.integers(1, 255))
    with pytest.raises(FrameError):
        decode_frame(bytes(raw))


@FAST
@given(st.binary(max_size=2000))
def test_cobs_round_trip_and_never_emits_the_delimiter(data):
    enc = cobs_encode(data)
    assert 0 not in enc
    assert len(enc) <= len(data) + 1 + len(data) // 254 + 1
    assert cobs_decode(enc) == data


@pytest.mark.parametrize("n", [253, 254, 255, 508, 509])
def test_cobs_run_boundaries(n):
    for data in (b"\x01" * n, b"\x01" * n + b"\x00", b"\x00" + b"\x01" * n):
        assert cobs_decode(cobs_encode(data)) == data


def stream_of(k, c=2, n=16, sid=3):
    data = np.arange(c * n * k, dtype=np.float32).reshape(c, n * k)
    return frames_from_block(sid, 10, 1000, data, n)


def feed_in_chunks(deframer, raw, cuts):
    out, pos = [], 0
    for cut in sorted(set(cuts)) + [len(raw)]:
        out += deframer.feed(raw[pos:cut])
        pos = cut
    return out + deframer.flush()


@FAST
@given(st.sampled_from(["cobs", "length"]), st.integers(3, 12), st.data())
def test_resync_after_arbitrary_corruption(wrap, k, data):
    """Whatever happens to a stretch of bytes: no frame is invented, every frame whose bytes were
    untouched is recovered, and the first-sample indices account for every lost sample."""
    fs = stream_of(k)
    records = [cobs_record(encode_frame(f)) if wrap == "cobs" else length_prefixed(encode_frame(f)) for f in fs]
    bounds = np.cumsum([0] + [len(r) for r in records])
    raw = b"".join(records)
    a = data.draw(st.integers(0, len(raw) - 1))
    b = data.draw(st.integers(a, min(len(raw), a + 200)))
    junk = data.draw(st.binary(max_size=120))
    damaged = raw[:a] + junk + raw[b:]
    cuts = data.draw(st.lists(st.integers(0, len(damaged)), max_size=8))
    deframer = CobsDeframer(3, 2) if wrap == "cobs" else LengthPrefixDeframer(3, 2)
    got = feed_in_chunks(deframer, damaged, cuts)
    originals = {f.seq: f for f in fs}
    for g in got:  # nothing invented
        assert g.seq in originals and same(g, originals[g.seq])
    # every frame entirely outside the damaged stretch survives (COBS: and its leading delimiter)
    lead = 1 if wrap == "cobs" else 0
    intact = [f.seq for f, s, e in zip(fs, bounds[:-1], bounds[1:])
              if (e <= a or s - lead >= b) and not (junk == b"" and a == b)]
    assert set(intact) <= {g.seq for g in got}
    # exact accounting: delivered samples + gap samples span the stream from first to last frame
    idx = [g.first_index for g in got]
    assert idx == sorted(idx)
    if got:
        delivered = sum(g.n for g in got)
        gaps = sum(y.first_index - x.end_index for x, y in zip(got, got[1:]))
        assert delivered + gaps == got[-1].end_index - got[0].first_index


def test_clean_stream_in_one_byte_chunks():
    fs = stream_of(5)
    for deframer, wrap in ((CobsDeframer(), cobs_record), (LengthPrefixDeframer(), length_prefixed)):
        raw = b"".join(wrap(encode_frame(f)) for f in fs)
        got = [g for i in range(len(raw)) for g in deframer.feed(raw[i:i + 1])]
        assert [g.seq for g in got] == [f.seq for f in fs]
        assert deframer.stats.corrupt == deframer.stats.discarded_bytes == 0


def test_corrupt_frame_is_counted_and_the_next_one_kept():
    fs = stream_of(3)
    raws = [bytearray(encode_frame(f)) for f in fs]
    raws[1][30] ^= 0x40
    for deframer, wrap in ((CobsDeframer(), cobs_record), (LengthPrefixDeframer(), length_prefixed)):
        got = deframer.feed(b"".join(wrap(bytes(r)) for r in raws))
        assert [g.seq for g in got] == [fs[0].seq, fs[2].seq]
        assert deframer.stats.corrupt == 1


def test_oversized_frames_are_refused():
    with pytest.raises(ValueError):
        encode_frame(Frame(1, 0, 0, np.zeros((2, (MAX_FRAME_SIZE // 8) + 1), np.float32)))


# --- the compiled COBS codec against its Python reference (issue 14) -----------------------------
def kernels():
    from hystbench.drivers.protocols import framing

    pair = framing._cobs_kernels()
    if pair is None:
        pytest.skip("numba is off (HYSTBENCH_JIT=0 or not installed): only the reference runs")
    return pair


def kernel_encode(data: bytes) -> bytes:
    src = np.frombuffer(data, dtype=np.uint8)
    dst = np.empty(src.size + src.size // 254 + 2, dtype=np.uint8)
    return dst[:kernels()[0](src, dst)].tobytes()


def kernel_decode(data: bytes) -> bytes:
    src = np.frombuffer(data, dtype=np.uint8)
    dst = np.empty(src.size, dtype=np.uint8)
    n = kernels()[1](src, dst)
    if n < 0:
        raise FrameError({-1: "zero byte inside a COBS record", -2: "COBS record truncated"}[n])
    return dst[:n].tobytes()


def same_outcome(f, g, data):
    """f(data) and g(data) give the same bytes, or both refuse with the same message."""
    try:
        want = f(data)
    except FrameError as err:
        with pytest.raises(FrameError, match=str(err)):
            g(data)
        return
    assert g(data) == want


#: bytes with long zero-free runs and many zeros, as ADC-quantised float32 samples have
cobs_inputs = st.lists(st.one_of(st.binary(max_size=600), st.just(b"\x00"), st.integers(250, 600).map(
    lambda n: bytes(i % 255 + 1 for i in range(n)))), max_size=8).map(b"".join)


@FAST
@given(cobs_inputs)
def test_cobs_kernel_encodes_the_reference_bytes_and_round_trips(data):
    enc = kernel_encode(data)
    assert enc == cobs_encode_reference(data) == cobs_encode(data)
    assert kernel_decode(enc) == cobs_decode_reference(enc) == data


@FAST
@given(st.binary(max_size=800), st.data())
def test_cobs_kernel_decodes_any_bytes_as_the_reference_does(data, draw):
    """Valid or not (a zero inside, a code running past the end): the same bytes or the same refusal."""
    enc = bytearray(cobs_encode_reference(data))
    for _ in range(draw.draw(st.integers(0, 3))):  # damage: a byte anywhere, zeros and codes included
        if enc:
            enc[draw.draw(st.integers(0, len(enc) - 1))] = draw.draw(st.sampled_from([0, 1, 2, 0xFE, 0xFF, 77]))
    cut = draw.draw(st.integers(0, len(enc)))  # truncation
    same_outcome(cobs_decode_reference, kernel_decode, bytes(enc[:cut]))


@pytest.mark.parametrize("data", [b"", b"\x00", b"\x00\x00", b"a\x00", b"\x01" * 253, b"\x01" * 254,
                                  b"\x01" * 254 + b"\x00", b"\x01" * 255, b"\x00" + b"\x01" * 508 + b"\x00",
                                  b"\x01" * 254 + b"\x00" + b"\x01" * 254])
def test_cobs_kernel_edge_cases_match_the_reference(data):
    """254-byte runs (a 0xFF code with no zero after it), a trailing zero, empty input: byte for byte."""
    assert kernel_encode(data) == cobs_encode_reference(data)
    assert kernel_decode(cobs_encode_reference(data)) == data


@pytest.mark.parametrize("record, message", [(b"\x03a\x00b", "zero byte inside"), (b"\x00", "zero byte inside"),
                                             (b"\x05abc", "truncated"), (b"\xff" + b"\x01" * 100, "truncated")])
def test_cobs_kernel_refuses_what_the_reference_refuses(record, message):
    for decode in (cobs_decode_reference, kernel_decode):
        with pytest.raises(FrameError, match=message):
            decode(record)


def test_cobs_deframer_on_the_kernel_equals_the_reference_on_a_quantised_stream(monkeypatch):
    """A float32 stream quantised like an ADC's (a fifth of its bytes are zero), with one damaged
    record: the kernel path hands out the same frames and counts as the reference."""
    x = (np.round(6 * np.sin(np.arange(4000) / 30) / (20 / 65536)) * (20 / 65536)).astype(np.float32)
    raws = [encode_frame(f) for f in frames_from_block(3, 0, 0, x[None, :], 500)]
    wire = bytearray(b"".join(b"\x00" + cobs_record(r) for r in raws))
    wire[len(wire) // 2] ^= 0x21
    assert kernels() and sum(r.count(0) for r in raws) > 0.15 * sum(map(len, raws))
    from hystbench.drivers.protocols import framing

    got = {}
    for name, decode in (("kernel", cobs_decode), ("reference", cobs_decode_reference)):
        monkeypatch.setattr(framing, "cobs_decode", decode)  # the deframer's codec: kernel, then reference
        d = CobsDeframer(3, 1)
        got[name] = ([(f.seq, f.first_index, f.samples.tobytes()) for f in d.feed(bytes(wire))], d.stats)
    assert got["kernel"] == got["reference"]
    assert got["kernel"][1].corrupt == 1 and len(got["kernel"][0]) == len(raws) - 1
