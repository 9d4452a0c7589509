"""CAN FD's batch receive path equals the frame-by-frame one: the source's decode (damaged and short
frames among good ones; the codec itself: test_can_stream.py) and the vectorised accept (gaps, lost
frames, stale and overlapping frames, flag changes), down to every counter; and through a real
python-can virtual bus.  The compiled CRC-32 of many short records (the CAN FD frames') is zlib's."""

import uuid
import zlib

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hystbench.blocks import BlockFlags
from hystbench.drivers.protocols import can_stream as cs
from hystbench.drivers.protocols.framing import Frame, FrameBatch, crc32_rows
from hystbench.drivers.stream import CanFrameSource, SampleStream

from .test_stream import FakeSource

FAST = settings(max_examples=120, deadline=None, suppress_health_check=[HealthCheck.too_slow])
HANG_S = 60.0


def frame(first, seq, sid=4, n=10, flags=0, channels=1):
    x = np.arange(first, first + n, dtype=np.float32) + 0.25  # each sample says its own index
    return Frame(sid, seq % (1 << 32), first, np.repeat(x[None, :], channels, axis=0), flags)


def batch_of(frames):
    """Frames of one shape as the batch a drain hands on (built field by field, no codec)."""
    def column(name):
        return np.array([getattr(f, name) for f in frames], dtype=np.int64)

    return FrameBatch(column("stream_id"), column("seq"), column("first_index"), column("flags"),
                      np.stack([f.samples for f in frames]))


def as_tuples(items):
    """Items (Frames or FrameBatches) as plain per-frame tuples."""
    out = []
    for item in items:
        for f in item.frames() if isinstance(item, FrameBatch) else [item]:
            out.append((f.stream_id, f.seq, f.first_index, f.flags, f.samples.tobytes()))
    return out


def corrupt(raw, at):
    b = bytearray(raw)
    b[at] ^= 0x10
    return bytes(b)


# --- the CAN source's decode ------------------------------------------------------------------------
def can_payloads(count, first=0, seq=0):
    """``count`` full CAN FD stream frames whose samples are codes first.. (each says its index)."""
    return cs.encode_frames(seq, first, (first + np.arange(17 * count)) * cs.LSB_V)


@FAST
@given(st.lists(st.sampled_from(["good", "good", "crc", "short_frame", "truncated"]), min_size=1, max_size=40))
def test_source_decode_equals_frame_by_frame_decode(kinds):
    """Whatever mix of damaged, short and truncated payloads: the same frames in the same order,
    and the same counters, as decoding one message at a time."""
    payloads, first = [], 0
    for i, kind in enumerate(kinds):
        n = 4 if kind == "short_frame" else 17
        raw = cs.encode_frames(i, first, (first + np.arange(n)) * cs.LSB_V)[0]
        first += n
        raw = {"crc": lambda r: corrupt(r, 40), "truncated": lambda r: r[:33]}.get(kind, lambda r: r)(raw)
        payloads.append(raw)
    batched = CanFrameSource(None, 0x184, stream_id=4)
    each = CanFrameSource(None, 0x184, stream_id=4)
    assert as_tuples(batched.decode(payloads)) == as_tuples(each.decode_each(payloads))
    assert batched.deframer_stats == each.deframer_stats
    assert batched.deframer_stats.frames == kinds.count("good") + kinds.count("short_frame")
    assert batched.deframer_stats.corrupt == kinds.count("crc") + kinds.count("truncated")
    assert batched.deframer_stats.discarded_bytes == 64 * kinds.count("crc") + 33 * kinds.count("truncated")


# --- the vectorised accept -------------------------------------------------------------------------
def queued(stream):
    """Every run the stream queued, as (first, samples bytes, flags), and its counters."""
    runs = [(first, data.tobytes(), flags) for first, data, flags in stream._runs]
    return runs, {k: v for k, v in stream.stats.as_dict().items()}


def accept_both(history, frames):
    """Stream A takes ``frames`` as one FrameBatch, stream B one Frame at a time, after the same
    ``history`` (per frame): their runs and counters."""
    a, b = (SampleStream("s", FakeSource([]), ["x"], 1e5) for _ in range(2))
    for s in (a, b):
        if history:
            s._accept(history)
    a._accept([batch_of(frames)])
    b._accept(frames)
    return queued(a), queued(b)


@FAST
@given(st.lists(st.tuples(st.integers(-25, 40), st.integers(-2, 5), st.sampled_from([0, 0, 0, 4])),
                min_size=1, max_size=30), st.booleans())
def test_batch_accept_equals_per_frame_accept(moves, with_history):
    """Frames that jump ahead (gaps), repeat (stale), step back partly (overlap), skip or repeat
    sequence numbers, change flags: the batch queues the same runs and counts the same as the
    frame-by-frame rule, after a history or from a fresh stream."""
    frames, first, seq = [], 100, 7
    for jump, seq_step, flags in moves:
        first, seq = max(0, first + jump), seq + seq_step
        frames.append(frame(first, seq, flags=flags))
    history = [frame(95, 3), frame(105, 4)] if with_history else []
    got, want = accept_both(history, frames)
    assert got == want


@FAST
@given(st.integers(-30, 30), st.integers(-3, 3), st.integers(1, 30), st.booleans())
def test_a_contiguous_batch_after_any_history_equals_per_frame_accept(jump, seq_jump, k, with_history):
    """The healthy drain (indices and sequence numbers contiguous, one flag value), after a history it
    may overlap, repeat or leave a gap to: the same runs and counters as frame by frame."""
    first, seq = 115 + jump, 5 + seq_jump
    frames = [frame(first + 10 * i, seq + i) for i in range(k)]
    history = [frame(95, 3), frame(105, 4)] if with_history else []
    got, want = accept_both(history, frames)
    assert got == want


def test_batch_accept_counts_a_sequence_gap_exactly():
    """Frames 3 and 4 (20 samples) never came: 2 frames lost, a block flagged GAP of exactly 20."""
    frames = [frame(10 * i, i) for i in range(10) if i not in (3, 4)]
    s = SampleStream("s", FakeSource([]), ["x"], 1e5)
    s._accept([batch_of(frames)])
    blocks = [s.read(0.0), s.read(0.0)]
    assert s.read(0.0) is None
    assert [(b.first_index, b.n, b.gap_samples) for b in blocks] == [(0, 30, 0), (50, 50, 20)]
    assert blocks[1].flags & BlockFlags.GAP
    assert s.stats.frames_lost == 2 and s.stats.gap_samples == 20 and s.stats.frames == 8
    np.testing.assert_array_equal(blocks[1].channels["x"], np.arange(50, 100) + 0.25)


def test_batch_accept_drops_stale_and_trims_overlapping_frames():
    frames = [frame(0, 0), frame(10, 1), frame(5, 1), frame(15, 2), frame(25, 3)]  # stale 5..14; 15..24 overlaps
    s = SampleStream("s", FakeSource([]), ["x"], 1e5)
    s._accept([batch_of(frames)])
    block = s.read(0.0)
    assert (block.first_index, block.n, block.gap_samples) == (0, 35, 0)
    np.testing.assert_array_equal(block.channels["x"], np.arange(35) + 0.25)
    assert s.stats.stale_frames == 1 and s.stats.frames == 4


def test_batch_of_another_channel_count_is_foreign_or_stale_as_per_frame():
    frames2 = [frame(i * 10, i, channels=2) for i in range(4)]
    got, want = accept_both([frame(0, 0), frame(10, 1)], frames2)
    assert got == want and got[1]["stale_frames"] == 2 and got[1]["deframer_foreign"] == 2


def test_an_empty_batch_changes_nothing():
    s = SampleStream("s", FakeSource([]), ["x"], 1e5)
    s._accept([frame(0, 0), batch_of([frame(10, 1)]).take(np.zeros(1, bool))])
    assert [(first, data.shape[1]) for first, data, _ in s._runs] == [(0, 10)] and s.stats.frames == 1


def test_frames_and_a_batch_in_one_accept_merge_into_one_run():
    """A reopen's pending frames then a drain's batch: one contiguous run, concatenated once."""
    s = SampleStream("s", FakeSource([]), ["x"], 1e5)
    s._accept([frame(0, 0), frame(10, 1), batch_of([frame(20 + 10 * i, 2 + i) for i in range(5)])])
    assert len(s._runs) == 1
    block = s.read(0.0)
    np.testing.assert_array_equal(block.channels["x"], np.arange(70) + 0.25)


# --- through a python-can virtual bus ----------------------------------------------------------------
def test_can_stream_through_a_virtual_bus_counts_damage_and_gaps_exactly():
    """A real stream over python-can: a corrupt message, a lost frame and a message of another CAN
    id among 31 good ones; the samples delivered are the ones sent (each sample's code is its index)."""
    can = pytest.importorskip("can")
    channel = f"test-batch-{uuid.uuid4().hex[:8]}"
    tx = can.Bus(interface="virtual", channel=channel, fd=True, receive_own_messages=False)
    rx = can.Bus(interface="virtual", channel=channel, fd=True, receive_own_messages=False)
    try:
        def send(raw, can_id=0x184):
            tx.send(can.Message(arbitration_id=can_id, data=raw, is_extended_id=False, is_fd=True))

        for i, raw in enumerate(can_payloads(34)):
            if i == 7:
                raw = corrupt(raw, 44)
            elif i == 20:
                continue  # lost on the way
            elif i == 25:
                send(raw, can_id=0x185)  # another node's stream: not ours
                continue
            send(raw)
        source = CanFrameSource(rx, 0x184, stream_id=4)
        with SampleStream("flux", source, ["x"], 1e5, stall_timeout_s=5.0) as s:
            blocks = []
            while sum(b.n for b in blocks) < 31 * 17:
                b = s.read(HANG_S)
                assert b is not None, "stream stopped delivering"
                blocks.append(b)
        x = np.concatenate([b.channels["x"] for b in blocks])
        idx = np.concatenate([b.first_index + np.arange(b.n) for b in blocks])
        np.testing.assert_array_equal(x, (idx * (10.0 / 2 ** 23)).astype(np.float32))
        missing = [i for k in (7, 20, 25) for i in range(17 * k, 17 * k + 17)]
        assert sorted(set(range(34 * 17)) - set(idx.tolist())) == missing
        assert s.stats.gap_samples == 3 * 17 and s.stats.frames == 31 and s.stats.frames_lost == 3
        assert source.deframer_stats.corrupt == 1 and source.deframer_stats.foreign == 0
    finally:
        tx.shutdown()
        rx.shutdown()


def test_sequence_numbers_that_wrap_at_16_bits_count_losses_across_the_wrap():
    """The CAN frame's u16 sequence wraps: 65535 then 2 is two frames lost (a 32-bit wrap would read
    the jump back as a reordering and count none)."""
    s = SampleStream("s", CanFrameSource(None, 0x184, stream_id=4), ["x"], 1e5)
    s._accept(s.source.decode(can_payloads(6, seq=65530)))  # 65530 .. 65535
    s._accept(s.source.decode(can_payloads(3, first=8 * 17, seq=2)))  # 0 and 1 never came
    assert s.stats.frames == 9 and s.stats.frames_lost == 2
    assert [(b.first_index, b.gap_samples) for b in (s.read(0.0), s.read(0.0))] == [(0, 0), (8 * 17, 2 * 17)]


def test_a_read_converts_to_si_as_float64_wire_times_scale():
    """The consumer's block: the float32 wire widened to float64 then scaled (a unit scale: the wire
    as is), checked against that computation done independently on the encoded samples."""
    s = SampleStream("s", FakeSource([]), ["x", "y"], 1e5, scale={"x": 1.0 / 3e4})
    f = frame(0, 0, channels=2)
    f.samples[1] *= -7.5
    s._accept([f])
    block = s.read(0.0)
    wire = f.samples.astype(np.float32)
    assert block.channels["x"].dtype == np.float64
    np.testing.assert_array_equal(block.channels["x"], wire[0].astype(np.float64) * (1.0 / 3e4))
    np.testing.assert_array_equal(block.channels["y"], wire[1].astype(np.float64))
    assert s.read(0.0) is None


def test_an_empty_look_raises_the_readers_error():
    """``read(0)`` on an empty stream: None while healthy, the reader's fatal error once it gave up."""
    from hystbench.errors import ConnectionLost

    s = SampleStream("s", FakeSource([]), ["x"], 1e5)
    assert s.read(0.0) is None
    s._error = ConnectionLost("s: gone")
    with pytest.raises(ConnectionLost, match="gone"):
        s.read(0.0)


@settings(max_examples=100, deadline=None)
@given(rows=st.integers(0, 40), size=st.integers(1, 300), seed=st.integers(0, 2**32 - 1))
def test_crc32_rows_is_zlibs_crc_of_each_rows_first_bytes(rows, size, seed):
    data = np.random.default_rng(seed).integers(0, 256, (rows, size), dtype=np.uint8)
    length = size - 4 if size > 4 else size
    want = [zlib.crc32(r[:length].tobytes()) for r in data]
    assert crc32_rows(data, length).tolist() == want
