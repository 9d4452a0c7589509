"""The reader's live edge: each transport says when a read took everything it held (``drained``),
and a stream remembers where such reads left it, so a command's first sample is bounded however far
behind the reading had fallen (``SampleStream.live_index_after``).  Each transport is the real one
(a TCP socket on 127.0.0.1, pyserial's loop://, python-can's virtual bus) with more queued than one
read takes: the first read must not claim the edge, the one that empties the queue must."""

import socket
import threading
import time
import uuid

import numpy as np
import pytest

from hystbench.drivers.protocols import can_stream
from hystbench.drivers.protocols.framing import Frame, cobs_record, encode_frame, length_prefixed
from hystbench.drivers.stream import CanFrameSource, FrameSource, SampleStream, SerialFrameSource, TcpFrameSource
from hystbench.drivers.protocols.framing import DeframerStats

HANG_S = 30.0  # a safety timeout: what is waited for is already queued, only a hang takes this long
N = 64  # samples per frame


def frames(count: int, first: int = 0) -> list[Frame]:
    return [Frame(3, k, first + N * k, np.full((1, N), k, np.float32)) for k in range(count)]


def read_until_drained(source: FrameSource) -> list[tuple[int, bool]]:
    """(frames, drained) of each read until one says drained (bounded: a hang is a failure)."""
    reads = []
    while not reads or not reads[-1][1]:
        got = source.read_frames(HANG_S)
        reads.append((len(got), source.drained))
        assert len(reads) < 1000, "never drained"
    return reads


def test_tcp_a_read_that_leaves_bytes_queued_is_not_the_edge_the_one_that_empties_it_is(monkeypatch):
    """Reads of 4 KiB (not 256) so that what is queued fits any machine's socket buffers."""
    from hystbench.drivers import stream

    monkeypatch.setattr(stream, "_TCP_READ", 4096)
    wire = b"".join(length_prefixed(encode_frame(f)) for f in frames(60))  # ~16 kB: several recvs
    with socket.create_server(("127.0.0.1", 0)) as server:
        source = TcpFrameSource(f"127.0.0.1:{server.getsockname()[1]}", stream_id=3, channels=1)
        source.open()
        conn, _ = server.accept()
        try:
            conn.sendall(wire)
            conn.shutdown(socket.SHUT_WR)
            reads = []
            while sum(n for n, _ in reads) < 60:
                reads.append((len(source.read_frames(HANG_S)), source.drained))
        finally:
            conn.close()
            source.close()
    assert len(reads) >= 4 and not reads[0][1]  # 4 KiB taken, more queued
    assert reads[-1][1]  # the last bytes: less than asked, so all there was


def test_serial_a_read_that_leaves_bytes_waiting_is_not_the_edge(monkeypatch):
    """pyserial's loop:// holds 4 KiB (a serial line's buffers are small: a backlog cannot hide
    there for long), so the read size is made smaller than what is queued."""
    pytest.importorskip("serial")
    from hystbench.drivers import stream

    monkeypatch.setattr(stream, "_SERIAL_READ", 1000)
    source = SerialFrameSource("loop://", stream_id=3, channels=1)
    source.open()
    try:
        wire = b"".join(cobs_record(encode_frame(f)) for f in frames(10))  # 2820 bytes
        source._port.write(wire)
        reads = read_until_drained(source)
    finally:
        source.close()
    assert len(reads) >= 3 and not reads[0][1] and not reads[1][1]


def test_can_a_drain_cut_at_its_batch_limit_is_not_the_edge():
    can = pytest.importorskip("can")
    channel = f"live-edge-{uuid.uuid4().hex[:8]}"
    tx = can.Bus(interface="virtual", channel=channel, fd=True, receive_own_messages=False)
    rx = can.Bus(interface="virtual", channel=channel, fd=True, receive_own_messages=False)
    try:
        small = can_stream.encode_frames(0, 0, np.zeros(17 * (CanFrameSource.max_batch + 10)))
        for raw in small:
            tx.send(can.Message(arbitration_id=0x184, data=raw, is_extended_id=False, is_fd=True))
        source = CanFrameSource(rx, 0x184, stream_id=3)
        first = source.read_frames(HANG_S)
        assert not source.drained  # max_batch messages taken, ten still queued
        rest = source.read_frames(HANG_S)
        assert source.drained
        assert sum(len(x) if not isinstance(x, Frame) else 1 for x in first + rest) == len(small)
    finally:
        tx.shutdown()
        rx.shutdown()


class ScriptedSource(FrameSource):
    """Hands out (frames, drained) pairs; once they run out, every read is empty and drained."""

    def __init__(self, script):
        self.script = list(script)
        self.deframer_stats = DeframerStats()
        self.done = threading.Event()

    def open(self):
        pass

    def close(self):
        pass

    def read_frames(self, timeout_s):
        if self.script:
            got, self.drained = self.script.pop(0)
            return got
        self.drained = True
        self.done.set()
        threading.Event().wait(min(timeout_s, 0.01))
        return []


def test_the_stream_bounds_the_clock_by_the_first_drained_read_after_the_moment_asked():
    before = time.monotonic()
    batches = frames(30)
    source = ScriptedSource([(batches[:10], False), (batches[10:20], False), (batches[20:], True)])
    with SampleStream("s", source, ["x"], 1e5, stall_timeout_s=HANG_S) as stream:
        assert source.done.wait(HANG_S)
        # the reads that did not drain say nothing: the first that did left the stream at 30 frames
        assert stream.live_index_after(before) == 30 * N
        assert stream.live_index_after(time.monotonic() + 3600.0) is None  # none began that late


def test_a_source_that_never_drains_bounds_nothing():
    source = ScriptedSource([(frames(5), False)])
    source.read_frames = lambda timeout_s, f=source.read_frames: (f(timeout_s), setattr(source, "drained", False))[0]
    with SampleStream("s", source, ["x"], 1e5, stall_timeout_s=HANG_S) as stream:
        assert source.done.wait(HANG_S)
        assert stream.live_index_after(0.0) is None


def test_a_stream_compiles_its_decoders_before_it_opens_the_transport():
    """The first COBS or CAN FD decode in a process compiles (3.4 s cold): on the reader thread,
    that was a backlog of seconds before the first sample.  ``start`` warms the source first."""
    pytest.importorskip("serial")
    from hystbench import jit
    from hystbench.drivers.protocols import framing

    if not jit.enabled():
        pytest.skip("numba is off: nothing to compile")
    compiled_at_open: list = []

    class Watched(SerialFrameSource):
        def open(self):
            compiled_at_open.append(bool(framing._cobs_kernels()[1].signatures))
            super().open()

    framing._cobs_kernels.cache_clear()
    with SampleStream("s", Watched("loop://", stream_id=3, channels=1), ["x"], 1e5, stall_timeout_s=HANG_S):
        pass
    assert compiled_at_open == [True]
    framing._crc_rows_kernel.cache_clear()
    CanFrameSource(None, 0x184, stream_id=3).warm()
    assert framing._crc_rows_kernel.cache_info().currsize == 1
