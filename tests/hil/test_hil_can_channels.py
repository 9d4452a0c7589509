"""The emulated bench's flux integrator streams on a virtual channel of its own: python-can's
virtual bus hands every handle of a channel every frame and filters in Python, so on one channel
the driver's command handle (filtered to replies and heartbeats, as a kernel would filter it on
socketcan) would still dequeue the 5 900 stream frames a second.  On the command channel a bus
analyser sees commands, replies and heartbeats only; the stream still delivers every sample."""

import can
import numpy as np

from hystbench.drivers.protocols import can_integrator as ci

from .conftest import expected_wire, skip_to, switched_on_at


def test_the_command_channel_carries_no_stream_frame(hil):
    where = hil.emu.addresses["flux_integrator"]
    node = where["node"]
    spy = can.Bus(interface="virtual", channel=where["can_channel"], receive_own_messages=False, fd=True)
    try:
        hil.bench.start_output()
        skip_to(hil, switched_on_at(hil))
        run = hil.bench.acquire(0.2)[-1]
        assert run.n >= 10_000  # >= 1000 stream frames went out while the spy listened
        np.testing.assert_allclose(run.channels["flux_Wb"], expected_wire(hil, "flux_Wb", run.first_index, run.n),
                                   rtol=1e-12, atol=0)
        hil.bench.integrator.read_status()  # a command and its reply on the command channel
        seen = []
        while (msg := spy.recv(0)) is not None:
            seen.append(msg.arbitration_id)
    finally:
        spy.shutdown()
    assert ci.command_id(node) in seen and ci.reply_id(node) in seen
    assert ci.stream_id(node) not in seen
    assert where["can_stream_channel"] != where["can_channel"]
    assert hil.bench.integrator.stream_channel == where["can_stream_channel"]
