"""The CAN FD stream frame (17 int24 samples in 64 bytes): byte-exact layout, round trips, short
frames, clipping, the check's power (every one- and two-bit error in the checked bytes is caught),
and the batch decoder equal to the one-by-one reference on any mix of damage."""

import zlib

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hystbench.drivers.protocols import can_stream as cs
from hystbench.drivers.protocols.framing import Frame, FrameBatch, FrameError

from .test_stream_batch import as_tuples

FAST = settings(max_examples=120, deadline=None, suppress_health_check=[HealthCheck.too_slow])
LSB = 10.0 / 2 ** 23  # the integrator's +-10 V full scale over a 24-bit ADC's 2**23 codes


def test_a_frame_built_by_hand_byte_by_byte_decodes_to_its_fields():
    """Layout of the module docstring, written here independently with int.to_bytes and zlib."""
    codes = [1, -1, 2 ** 23 - 1, -(2 ** 23 - 1), 0x123456, -0x123456]
    body = bytes([len(codes), 4]) + (0xBEEF).to_bytes(2, "little") + (2 ** 47 + 5).to_bytes(6, "little")
    body += b"".join(c.to_bytes(3, "little", signed=True) for c in codes) + bytes(3 * (17 - len(codes)))
    assert len(body) == 61
    data = body + (zlib.crc32(body) & 0xFFFFFF).to_bytes(3, "little")
    f = cs.decode_frame(data, 4)
    assert (f.stream_id, f.seq, f.first_index, f.flags, f.n) == (4, 0xBEEF, 2 ** 47 + 5, 4, 6)
    np.testing.assert_array_equal(f.samples[0], np.float32(np.array(codes) * LSB))
    # and the encoder writes exactly these bytes for those voltages
    assert cs.encode_frames(0xBEEF, 2 ** 47 + 5, np.array(codes) * LSB, flags=4) == [data]


def test_encoder_cuts_runs_of_17_numbers_them_and_shortens_only_the_last():
    raws = cs.encode_frames(65534, 1000, np.zeros(40))
    frames = [cs.decode_frame(r, 4) for r in raws]
    assert [len(r) for r in raws] == [64, 64, 64]
    assert [(f.seq, f.first_index, f.n) for f in frames] == [(65534, 1000, 17), (65535, 1017, 17), (0, 1034, 6)]
    assert cs.encode_frames(0, 0, np.zeros(0)) == []


def test_voltages_round_to_the_nearest_code_and_clip_at_full_scale():
    v = np.array([0.4 * LSB, 0.6 * LSB, -0.6 * LSB, 3.3, -3.3, 10.0, 11.0, -12.0])
    got = cs.decode_frame(cs.encode_frames(0, 0, v)[0], 4).samples[0].astype(np.float64)
    want = np.array([0, 1, -1, round(3.3 / LSB), -round(3.3 / LSB), 2 ** 23 - 1, 2 ** 23 - 1, -(2 ** 23 - 1)]) * LSB
    np.testing.assert_allclose(got, want, rtol=1e-7, atol=0)  # float32 of the code's voltage
    assert np.abs(got[3] - 3.3) <= LSB / 2 + 3.3 * 2 ** -24


def test_an_index_beyond_48_bits_is_refused():
    with pytest.raises(ValueError, match="48 bits"):
        cs.encode_frames(0, 2 ** 48 - 10, np.zeros(17))


def test_every_one_and_two_bit_error_in_the_checked_bytes_is_caught():
    """The check is linear in the message (CRC-32 truncated to 24 bits): an error pattern goes
    unseen only if its syndrome is 0.  The 488 single-bit syndromes are all non-zero (every one-bit
    error caught) and all different (no two-bit error's syndrome, their XOR, is 0)."""
    zero = bytes(61)
    base = zlib.crc32(zero) & 0xFFFFFF
    syndromes = set()
    for bit in range(61 * 8):
        b = bytearray(zero)
        b[bit // 8] ^= 1 << (bit % 8)
        syndromes.add((zlib.crc32(bytes(b)) & 0xFFFFFF) ^ base)
    assert 0 not in syndromes and len(syndromes) == 61 * 8


def test_a_corrupted_check_or_count_is_refused_by_both_decoders():
    raw = bytearray(cs.encode_frames(3, 0, np.ones(17))[0])
    for at, flip in ((30, 0x10), (62, 0x01)):
        b = bytearray(raw)
        b[at] ^= flip
        with pytest.raises(FrameError, match="CRC"):
            cs.decode_frame(bytes(b), 4)
        assert cs.decode_frames([bytes(b)] * 9, 4) == ([], 9)
    b = bytearray(raw)  # a count of 18 with a matching check: still impossible
    b[0] = 18
    b[61:] = (zlib.crc32(bytes(b[:61])) & 0xFFFFFF).to_bytes(3, "little")
    with pytest.raises(FrameError, match="sample count"):
        cs.decode_frame(bytes(b), 4)
    assert cs.decode_frames([bytes(b)], 4) == ([], 1)


kinds = st.sampled_from(["full", "full", "full", "short", "crc", "count", "truncated"])


@FAST
@given(st.lists(kinds, min_size=1, max_size=40), st.integers(0, 2 ** 16 - 1))
def test_batch_decode_equals_one_by_one_decode(mix, seq0):
    """Any mix of full, short, damaged and truncated fields: the same frames in the same order (runs
    of full ones batched, short ones on their own) and the same number refused."""
    payloads, first = [], 10 ** 9
    rng = np.random.default_rng(len(mix))
    for i, kind in enumerate(mix):
        n = 5 if kind == "short" else 17
        raw = cs.encode_frames(seq0 + i, first, rng.uniform(-9, 9, n))[0]
        first += n
        if kind == "crc":
            raw = raw[:20] + bytes([raw[20] ^ 0x08]) + raw[21:]
        elif kind == "count":
            raw = bytes([0]) + raw[1:]
        elif kind == "truncated":
            raw = raw[:48]
        payloads.append(raw)
    got, refused = cs.decode_frames(payloads, 4)
    want, want_refused = [], 0
    for p in payloads:
        try:
            want.append(cs.decode_frame(p, 4))
        except FrameError:
            want_refused += 1
    assert as_tuples(got) == as_tuples(want) and refused == want_refused
    assert refused == sum(k in ("crc", "count", "truncated") for k in mix)
    assert all(isinstance(x, Frame) and x.n == 5 or isinstance(x, FrameBatch) for x in got)


def test_a_healthy_drain_is_one_batch_with_its_short_frame_after_it():
    raws = cs.encode_frames(0, 0, np.linspace(-1, 1, 17 * 12 + 3))
    items, refused = cs.decode_frames(raws, 4)
    assert refused == 0 and [type(i) for i in items] == [FrameBatch, Frame]
    assert len(items[0]) == 12 and items[0].samples.shape == (12, 1, 17) and items[1].n == 3
