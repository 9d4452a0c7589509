"""pymeasure-style ``expected_protocol`` for our transports: a scripted TCP peer on 127.0.0.1 that
checks every byte a driver writes against a transcript and answers with the scripted reply.

It sits behind the driver's real transport (``socket://`` for serial-style drivers, Modbus TCP or
RTU-over-socket for pymodbus), so the bytes checked are the bytes that would go on the wire.
"""

from __future__ import annotations

import socket
import threading

import pytest

from hystbench.deadline import Deadline

Transcript = list[tuple[bytes, bytes | None]]


class ScriptedPeer:
    def __init__(self, transcript: Transcript, timeout_s: float = 3.0) -> None:
        self.transcript = list(transcript)
        self.timeout_s = timeout_s
        self.done = 0
        self.mismatch: tuple[int, bytes, bytes] | None = None
        self.extra = b""
        self._sock = socket.create_server(("127.0.0.1", 0))
        self._sock.settimeout(timeout_s)
        self.port = self._sock.getsockname()[1]
        self.url = f"socket://127.0.0.1:{self.port}"
        self.address = f"127.0.0.1:{self.port}"
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _read_exact(self, conn: socket.socket, n: int, deadline: Deadline) -> bytes:
        buf = b""
        while len(buf) < n and not deadline.expired:
            conn.settimeout(max(0.01, deadline.left()))
            try:
                chunk = conn.recv(n - len(buf))
            except socket.timeout:
                break
            if not chunk:
                break
            buf += chunk
        return buf

    def _run(self) -> None:
        try:
            conn, _ = self._sock.accept()
        except OSError:
            return
        with conn:
            for i, (expect, reply) in enumerate(self.transcript):
                got = self._read_exact(conn, len(expect), Deadline(self.timeout_s))
                if got != expect:
                    self.mismatch = (i, expect, got)
                    return
                if reply:
                    conn.sendall(reply)
                self.done = i + 1
            deadline = Deadline(self.timeout_s)
            while not deadline.expired:  # after the script only EOF may come
                conn.settimeout(max(0.01, deadline.left()))
                try:
                    chunk = conn.recv(4096)
                except socket.timeout:
                    break
                if not chunk:
                    break
                self.extra += chunk

    def check(self) -> None:
        self._thread.join(timeout=self.timeout_s + 1)
        self._sock.close()
        assert self.mismatch is None, (
            f"step {self.mismatch[0]}: expected {self.mismatch[1]!r}, driver wrote {self.mismatch[2]!r}")
        assert self.done == len(self.transcript), f"only {self.done} of {len(self.transcript)} steps ran"
        assert self.extra == b"", f"driver wrote {self.extra!r} after the transcript"


@pytest.fixture
def scripted_peer():
    peers: list[ScriptedPeer] = []

    def make(transcript: Transcript, timeout_s: float = 3.0) -> ScriptedPeer:
        peer = ScriptedPeer(transcript, timeout_s)
        peers.append(peer)
        return peer

    yield make
    for p in peers:
        p._sock.close()
