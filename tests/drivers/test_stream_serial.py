"""The serial frame source on a real pseudo-terminal: every byte of the bursts read, and reading
does not reconfigure the port each time (pyserial's ``timeout`` setter runs tcgetattr/tcsetattr on
every set)."""

import os
import tty

import numpy as np

from hystbench.drivers.protocols.framing import Frame, cobs_record, encode_frame
from hystbench.drivers.stream import SerialFrameSource


def records(k):
    return b"".join(b"\x00" + cobs_record(encode_frame(Frame(2, i, 50 * i, np.full((1, 50), i + 0.5, np.float32), 0)))
                    for i in range(k))


def read_all(src, k):
    frames = []
    while len(frames) < k:  # the pty may hand the burst over in pieces: read until all came
        got = src.read_frames(60.0)  # a safety timeout only: the bytes are already written
        assert got, "nothing within 60 s (a hang)"
        frames += got
    return frames


def test_reading_does_not_reconfigure_the_port_and_loses_no_byte():
    master, slave = os.openpty()
    tty.setraw(slave)
    src = SerialFrameSource(os.ttyname(slave), stream_id=2, channels=1)
    try:
        src.open()
        os.write(master, records(2))
        assert [f.first_index for f in read_all(src, 2)] == [0, 50]  # the port has the reader's timeout now
        calls = []
        reconfigure = src._port._reconfigure_port
        src._port._reconfigure_port = lambda *a, **k: (calls.append(1), reconfigure(*a, **k))
        for _ in range(3):
            os.write(master, records(4))
            frames = read_all(src, 4)
            assert [f.first_index for f in frames] == [0, 50, 100, 150]
            np.testing.assert_array_equal(frames[3].samples, np.full((1, 50), 3.5, np.float32))
        assert calls == []  # pyserial's timeout setter reconfigures the port: only on a change
    finally:
        src.close()
        os.close(master)
        os.close(slave)
