"""``SampleStream.wait_until``: the acquisition loop gathering a block sleeps until the stream it
waits for holds the samples it needs, instead of waking for every short run the reader hands on
(a pty gives 4 kB a read, a CAN drain a few hundred frames: hundreds of runs a second)."""

import threading

import numpy as np

from hystbench.drivers.protocols.framing import DeframerStats, Frame
from hystbench.drivers.stream import FrameSource, SampleStream

HANG_S = 30.0  # a safety timeout: only a hang takes this long
N = 64  # samples per frame


class OneFrameAtATime(FrameSource):
    """Each read hands on one frame (so each becomes a run of its own), once the test says so."""

    def __init__(self, count: int) -> None:
        self.frames = [Frame(3, k, N * k, np.full((1, N), k, np.float32)) for k in range(count)]
        self.deframer_stats = DeframerStats()
        self.go = threading.Semaphore(0)
        self.reading = threading.Semaphore(0)  # released each time a read begins (the last run accepted)

    def open(self):
        pass

    def close(self):
        pass

    def read_frames(self, timeout_s):
        self.reading.release()
        self.drained = True
        if self.frames and self.go.acquire(timeout=timeout_s):
            return [self.frames.pop(0)]
        return []


def test_the_consumer_sleeps_through_short_runs_and_wakes_once_they_reach_the_index():
    source = OneFrameAtATime(10)
    stream = SampleStream("s", source, ["x"], 1e5, stall_timeout_s=HANG_S)
    waiting = threading.Event()
    wakes: list[int] = []  # where the stream stood at each wake-up call the reader made

    class Watched(threading.Condition):
        def wait(self, timeout=None):
            waiting.set()
            return super().wait(timeout)

        def notify_all(self):
            wakes.append(stream._queued_end())
            super().notify_all()

    stream._cond = Watched()
    result = {}
    with stream:
        waiter = threading.Thread(target=lambda: result.setdefault("reached", stream.wait_until(10 * N, HANG_S)))
        waiter.start()
        assert waiting.wait(HANG_S)
        for _ in range(10):  # ten runs, one frame each, each accepted before the next comes
            assert source.reading.acquire(timeout=HANG_S)
            source.go.release()
        waiter.join(HANG_S)
        assert [stream.read(HANG_S).n for _ in range(10)] == [N] * 10  # ten runs, all there to read
    assert result == {"reached": True}
    assert wakes == [10 * N]  # woken once, when the tenth run came; not once a run


def test_wait_until_says_so_when_the_samples_do_not_come():
    source = OneFrameAtATime(2)
    with SampleStream("s", source, ["x"], 1e5, stall_timeout_s=HANG_S) as stream:
        source.go.release()
        assert stream.wait_until(N, HANG_S)
        assert not stream.wait_until(2 * N, 0.05)  # the second frame is never let through
