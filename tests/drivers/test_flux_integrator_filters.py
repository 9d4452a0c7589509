"""The integrator driver's command handle takes only replies and heartbeats: the CAN FD stream
(5 900 frames a second) is left to the stream handle, so on socketcan the kernel filters it out
instead of the heartbeat thread draining every frame in Python."""

import uuid

import can

from hystbench.drivers.flux_integrator import CanFluxIntegrator
from hystbench.drivers.protocols import can_integrator as ci

from .test_flux_integrator import CLOSE, NODE, OPEN, REPLY_S, CanPeer


def test_the_command_handle_filters_out_the_stream():
    channel = f"test-{uuid.uuid4().hex}"
    peer = CanPeer(channel, OPEN + CLOSE)
    other = peer.bus  # the instrument's own handle: its transcript does not see what it sends
    with CanFluxIntegrator(channel=channel, node=NODE, timeout_s=REPLY_S) as f:
        for k in range(50):
            other.send(can.Message(arbitration_id=ci.stream_id(NODE), data=bytes([k]) * 64, is_extended_id=False,
                                   is_fd=True))
        other.send(can.Message(arbitration_id=ci.heartbeat_id(NODE), data=b"\x05\x01", is_extended_id=False))
        got = f._bus.recv(REPLY_S)  # the 50 stream frames came first on the wire
        assert got is not None and got.arbitration_id == ci.heartbeat_id(NODE)
        assert {flt["can_id"] for flt in f._bus.filters} == {ci.reply_id(NODE), ci.heartbeat_id(NODE)}
    peer.check()
