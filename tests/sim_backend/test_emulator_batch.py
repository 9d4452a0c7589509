"""The emulators' fast stream path: a block's frames encoded as one numpy batch must be the very bytes
the per-frame codec (``framing.encode_frame``) gives; faults armed at a sample index still hit
exactly their frames; the integrator's virtual-bus handle delivers one Message per frame to every
other handle of the channel and none to itself.  No sleeps: sends are synchronous, receives wait
on the queue with a safety timeout only."""

from __future__ import annotations

import itertools

import can
import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from hystbench.blocks import SampleBlock
from hystbench.drivers.protocols import can_integrator as ci, can_stream
from hystbench.drivers.protocols.framing import FrameError, encode_frame, frames_from_block
from hystbench.sim_backend.emulators.common import Faults, FrameEmitter, encode_frames
from hystbench.sim_backend.emulators.flux_integrator import FluxIntegratorEmulator, emulator_bus

FS = 100_000.0
HANG_S = 30.0  # only turns a hang into a failure
_channels = itertools.count()


def per_frame(stream_id, seq0, first, data, spf, flags):
    return [encode_frame(f) for f in frames_from_block(stream_id, seq0, first, data, spf, flags)]


@settings(max_examples=200, deadline=None)
@given(n=st.integers(0, 2500), spf=st.sampled_from([1, 3, 10, 250, 500, 1000]), channels=st.integers(1, 3),
       seq0=st.one_of(st.integers(0, 100), st.integers((1 << 32) - 300, (1 << 32) - 1)),
       first=st.integers(-(1 << 40), 1 << 40), flags=st.integers(0, 0xFFFF), stream_id=st.integers(0, 255),
       seed=st.integers(0, 2**32 - 1))
def test_batch_encoded_frames_are_byte_identical_to_the_per_frame_codec(n, spf, channels, seq0, first, flags,
                                                                        stream_id, seed):
    data = np.random.default_rng(seed).standard_normal((channels, n)) * 10.0 ** np.arange(channels)[:, None]
    assert encode_frames(stream_id, seq0, first, data, spf, flags) == per_frame(stream_id, seq0, first, data, spf,
                                                                                flags)


def test_batch_encoding_keeps_the_codecs_refusals():
    for shape, spf in (((300, 4), 2), ((1, 20000), 20000)):  # 300 channels; a 80 kB frame
        data = np.zeros(shape)
        for encode in (encode_frames, per_frame):
            try:
                encode(1, 0, 0, data, spf, 0)
            except ValueError:
                continue
            raise AssertionError(f"{encode.__name__} accepted {shape} in frames of {spf}")


def can_blocks(first, count, block=1000):
    x = np.arange(first, first + count * block, dtype=np.float64) * 1e-3
    return [x[k * block:(k + 1) * block] for k in range(count)]


def can_emitter(faults):
    """The integrator emulator's emitter: 17 samples a CAN FD frame (``can_stream``), u16 sequence."""
    return FrameEmitter(4, can_stream.SAMPLES_PER_FRAME, faults, encode=can_stream.encode_frames,
                        seq_modulus=can_stream.SEQ_MODULUS)


def test_can_fd_faults_at_a_sample_index_hit_exactly_those_frames_in_a_batch():
    """17 samples per CAN FD frame, 1000-sample blocks (58 frames and a short one of 14 each):
    faults armed mid-block land on the first frame that starts at or after their index, not on
    the block's first frame."""
    faults = Faults()
    em = can_emitter(faults)
    faults.arm("drop_frames", 3, at_index=1234)  # frames 1238, 1255, 1272
    faults.arm("corrupt_frames", 2, at_index=2005)  # frames 2017, 2034
    faults.silence(2995, 30)  # frames 3000, 3017 (2986 starts before the span, 3034 after it)
    got = []
    for k, data in enumerate(can_blocks(0, 4)):
        for raw in em.emit(1000 * k, data[None, :]):
            try:
                got.append(can_stream.decode_frame(raw, 4).first_index)
            except FrameError:
                got.append(-1)
    starts = [1000 * k + 17 * j for k in range(4) for j in range(59)]
    expected = [-1 if i in (2017, 2034) else i for i in starts if i not in (1238, 1255, 1272, 3000, 3017)]
    assert got == expected
    assert (em.dropped, em.corrupted, em.sent) == (5, 2, 4 * 59 - 5)
    assert faults.drop_frames == 0 and faults.corrupt_frames == 0
    assert em.seq == 4 * 59  # dropped frames use their sequence numbers: the receiver sees the gap


def test_a_fault_armed_for_a_later_block_leaves_the_earlier_frames_alone():
    faults = Faults()
    em = can_emitter(faults)
    em.seq = 65530  # and the sequence wraps at 16 bits
    faults.arm("drop_frames", 1, at_index=5000)
    frames = [can_stream.decode_frame(r, 4) for r in em.emit(0, can_blocks(0, 1)[0][None, :])]
    assert [f.first_index for f in frames] == list(range(0, 1000, 17))
    assert [f.seq for f in frames] == [(65530 + j) % 65536 for j in range(59)]
    assert faults.drop_frames == 1  # still armed for its own frame


def drain(bus: can.BusABC, arbitration_id: int, n: int) -> list[can.Message]:
    out = []
    while len(out) < n:
        msg = bus.recv(HANG_S)
        assert msg is not None, f"only {len(out)} of {n} messages arrived"
        if msg.arbitration_id == arbitration_id:
            out.append(msg)
    return out


def test_emulator_bus_hands_each_other_handle_every_message_and_not_the_sender():
    channel = f"test-emulator-bus-{next(_channels)}"
    tx = emulator_bus("virtual", channel)
    rx = [can.Bus(interface="virtual", channel=channel, receive_own_messages=False, fd=True) for _ in range(2)]
    try:
        sent = [bytes(range(k, k + 64)) for k in range(5)]
        for data in sent:
            tx.send(can.Message(arbitration_id=0x190, data=data, is_extended_id=False, is_fd=True,
                                bitrate_switch=True), timeout=0.5)
        got = [drain(r, 0x190, len(sent)) for r in rx]
        for msgs in got:
            assert [bytes(m.data) for m in msgs] == sent
            assert all(m.is_fd and m.bitrate_switch and m.is_rx and m.channel == channel for m in msgs)
        assert all(a is b for a, b in zip(*got))  # one Message for all receivers: no copy per receiver
        assert tx.recv(0.0) is None  # nothing came back to the sender
        rx[0].send(can.Message(arbitration_id=0x610, data=b"\x01", is_extended_id=False), timeout=0.5)
        assert drain(tx, 0x610, 1)[0].data == b"\x01"  # and it still receives the others' messages
    finally:
        for bus in (tx, *rx):
            bus.shutdown()


def test_integrator_stream_reaches_both_driver_handles_intact():
    """The emulator's block -> CAN FD frames -> a driver's two stock handles (commands, stream)."""
    channel = f"test-integrator-{next(_channels)}"
    rx = [can.Bus(interface="virtual", channel=channel, receive_own_messages=False, fd=True) for _ in range(2)]
    emu = FluxIntegratorEmulator(channel=channel, true_turns=10)
    try:
        emu.state["stream"] = True
        flux = np.linspace(-8e-6, 8e-6, 1000)  # within the +-10 V output
        emu.on_block(SampleBlock(3000, FS, {"flux_Wb": flux}))
        volts = flux * 1e5 * 10 / 1  # gain 1e5 V/Wb, 10 true turns, 1 set turn
        codes = np.round(volts / (10.0 / 2 ** 23))  # the 24-bit ADC's codes: +-10 V over 2**23
        for r in rx:
            frames = [can_stream.decode_frame(bytes(m.data), 4) for m in drain(r, ci.stream_id(emu.node), 59)]
            assert [f.first_index for f in frames] == list(range(3000, 4000, 17))
            assert [f.seq for f in frames] == list(range(59))
            np.testing.assert_array_equal(np.concatenate([f.samples[0] for f in frames]),
                                          np.float32(codes * (10.0 / 2 ** 23)))
    finally:
        emu.close()
        for bus in rx:
            bus.shutdown()


def test_a_batch_send_delivers_in_order_and_wakes_a_waiting_receiver():
    """``send_batch``: every message, in order, to each other handle; a receiver already blocked
    in ``recv`` wakes for it (the batch notifies the queue as ``Queue.put`` does)."""
    import threading

    channel = f"test-emulator-batch-{next(_channels)}"
    tx = emulator_bus("virtual", channel)
    bounded = can.Bus(interface="virtual", channel=channel, receive_own_messages=False, fd=True, rx_queue_size=1000)
    waiting = can.Bus(interface="virtual", channel=channel, receive_own_messages=False, fd=True)
    got: list = []
    reader = threading.Thread(target=lambda: got.extend(drain(waiting, 0x190, 50)))
    reader.start()
    try:
        msgs = [can.Message(arbitration_id=0x190, data=k.to_bytes(8, "little"), is_extended_id=False, is_fd=True)
                for k in range(50)]
        tx.send_batch(msgs, timeout=0.5)
        reader.join(HANG_S)
        assert not reader.is_alive()
        for received in (got, drain(bounded, 0x190, 50)):
            assert [int.from_bytes(m.data, "little") for m in received] == list(range(50))
        assert tx.recv(0.0) is None
    finally:
        reader.join(HANG_S)
        for bus in (tx, bounded, waiting):
            bus.shutdown()


def test_a_stream_frame_is_the_message_python_can_would_make():
    """The emulator's fast stream frame: every slot as ``can.Message``'s own constructor sets it."""
    from hystbench.sim_backend.emulators.flux_integrator import stream_frame_type

    data = bytes(range(64))
    fast = stream_frame_type()(0x190, data)
    ref = can.Message(arbitration_id=0x190, data=data, is_extended_id=False, is_fd=True, bitrate_switch=True)
    assert isinstance(fast, can.Message)
    slots = [s for k in type(ref).__mro__ for s in getattr(k, "__slots__", ()) if s != "__weakref__"]
    assert {s: getattr(fast, s) for s in slots} == {s: getattr(ref, s) for s in slots}
    assert type(fast.data) is bytearray and fast.equals(ref, timestamp_delta=None)
