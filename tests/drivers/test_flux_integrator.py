"""Flux integrator driver: byte-exact CAN transcripts (identifier + data of every frame) on a
python-can virtual bus, refusals, timeouts, and the CAN FD stream."""

import threading
import uuid

import can
import numpy as np
import pytest

from hystbench.drivers.flux_integrator import CanFluxIntegrator, IntegratorError
from hystbench.drivers.protocols import can_integrator as ci, can_stream
from hystbench.errors import ConfigError, InstrumentTimeout

h = bytes.fromhex
NODE = 0x10
REPLY_S = 10.0  # the drivers' timeout where a reply is scripted: generous, the reply always comes
HANG_S = 60.0  # the peer's wait for the next command: only a hang takes this long


class CanPeer:
    """Checks each command frame (id, data) and answers with the scripted frames."""

    def __init__(self, channel, transcript):
        self.bus = can.Bus(interface="virtual", channel=channel, receive_own_messages=False, fd=True)
        self.transcript, self.done, self.mismatch = transcript, 0, None
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self):
        for i, ((cid, data), replies) in enumerate(self.transcript):
            msg = self.bus.recv(HANG_S)
            if msg is None or (msg.arbitration_id, bytes(msg.data)) != (cid, data):
                self.mismatch = (i, (cid, data), msg and (msg.arbitration_id, bytes(msg.data)))
                return
            for rid, rdata, fd in replies:
                self.bus.send(can.Message(arbitration_id=rid, data=rdata, is_extended_id=False, is_fd=fd))
            self.done = i + 1

    def check(self):
        self._thread.join(HANG_S)
        self.bus.shutdown()
        assert self.mismatch is None, self.mismatch
        assert self.done == len(self.transcript)


CMD, REPLY = 0x610, 0x590
OPEN = [((CMD, h("01000000 00000000")), [(REPLY, h("01000000 05014946"), False)]),  # identify: FI, 1.5
        ((CMD, h("05000000 00000000")), [(REPLY, h("05000000 0050c347"), False)]),  # gain 1e5 (f32)
        ((CMD, h("07000000 00000000")), [(REPLY, h("07000000 01000000"), False)])]  # turns 1
CLOSE = [((CMD, h("09000000 00000000")), [(REPLY, h("09000000 00000000"), False)])]  # stream off


@pytest.fixture
def channel():
    return f"test-{uuid.uuid4().hex}"


def test_open_configure_status_byte_exact(channel):
    peer = CanPeer(channel, OPEN + [
        ((CMD, h("04000000 00a00c48")), [(0x710, h("0509"), False), (REPLY, h("04000000 00a00c48"), False)]),
        ((CMD, h("06000000 0a000000")), [(REPLY, h("06000000 0a000000"), False)]),
        ((CMD, h("02000000 00000000")), [(REPLY, h("02000000 00000000"), False)]),
        ((CMD, h("08000000 00000000")), [(REPLY, h("08000000 05000000"), False)]),
    ] + CLOSE)
    with CanFluxIntegrator(channel=channel, node=NODE, timeout_s=REPLY_S) as f:
        assert f.firmware == "1.5" and f.settings == {"gain_v_per_wb": 1e5, "turns": 1}
        f.configure(gain_v_per_wb=1.44e5, turns=10)
        f.reset()
        st = f.read_status()
        assert not st.ok and st.faults == ("OVERLOAD",) and st.values["integrating"]
        assert f.last_heartbeat is not None and f.last_heartbeat[1] == 0x09
    peer.check()


def test_refusal_and_timeout(channel):
    peer = CanPeer(channel, OPEN + [
        ((CMD, h("03000000 01000000")), [(REPLY, h("03030000 00000000"), False)]),
        ((CMD, h("08000000 00000000")), []),
    ] + CLOSE)
    with CanFluxIntegrator(channel=channel, node=NODE, timeout_s=REPLY_S) as f:
        with pytest.raises(IntegratorError, match=r"hold\(1\) -> result 3 \(not allowed now\)"):
            f.hold(True)
        f.timeout_s = 0.3  # no reply is scripted: this one must run out
        with pytest.raises(InstrumentTimeout, match=r"no answer to 'get_status\(0x08\)' within 0.3 s"):
            f.read_status()
        with pytest.raises(ConfigError, match="set_turns 0"):
            f.set_turns(0)
        f.timeout_s = REPLY_S
    peer.check()


def test_can_fd_stream_frames_become_flux_samples(channel):
    codes = np.arange(40) * 100_003 - 2_000_000  # 24-bit codes, both signs
    frames = can_stream.encode_frames(0, 500, codes * (10.0 / 2 ** 23))  # 17 + 17 + 6 samples
    assert len(frames) == 3
    stream_frames = [(ci.stream_id(NODE), raw, True) for raw in frames]
    peer = CanPeer(channel, OPEN + [
        ((CMD, h("09000000 01000000")), [(REPLY, h("09000000 00000000"), False)]),
        ((CMD, h("05000000 00000000")), [(REPLY, h("05000000 00002041"), False)] + stream_frames),  # gain 10
    ] + CLOSE)
    with CanFluxIntegrator(channel=channel, node=NODE, timeout_s=REPLY_S) as f:
        with f.open_stream() as s:
            got = [s.read(HANG_S, max_samples=40)]
            while None not in got and sum(b.n for b in got) < 40:
                got.append(s.read(HANG_S))
    assert None not in got, "the stream stopped delivering"
    assert got[0].first_index == 500 and sum(b.n for b in got) == 40
    want = np.float32(codes * (10.0 / 2 ** 23)).astype(np.float64) * (1 / 10.0)  # the wire's float32 / gain
    np.testing.assert_array_equal(np.concatenate([b.channels["flux_Wb"] for b in got]), want)
    peer.check()
