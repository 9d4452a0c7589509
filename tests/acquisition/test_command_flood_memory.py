"""The daemon's memory under the issue's flood (issue 26): 20 client sessions x 50 commands with a
10 kB payload, from plain zenoh clients (zenoh's defaults: shared memory on) on loopback, against
a real ``hystbench daemon`` process.  Each such session used to add its 16 MiB shared-memory
segment to the daemon for good (+259 MB in the issue); now the RSS after the flood stays within
a few messages' worth of the per-message cap of the daemon's session, and every refused command
is in the log: one line each up to the budget, the rest in the lines that count them.  Bounded
in count (1000 commands) and, for a hang, in time (HANG_S per reply)."""

from __future__ import annotations

import os

import pytest

from benchmarks import bench_command_flood as fl
from hystbench.acquisition.zenoh_bus import MAX_COMMAND_BYTES, MAX_MESSAGE_BYTES

SESSIONS, COMMANDS, SIZE = 20, 50, 10_000
#: What the flood may leave behind: a few messages' worth of the largest one the daemon's session
#: reassembles (buffers and threads zenoh keeps), far below one session's 16 MiB segment.
BOUND_BYTES = 8 * MAX_MESSAGE_BYTES


@pytest.mark.skipif(not os.path.exists("/proc/self/status"), reason="reads the RSS from /proc")
def test_a_flood_of_10_kB_commands_leaves_the_daemons_rss_bounded():
    assert SIZE < MAX_COMMAND_BYTES  # parsed and refused by the bench, not by the cap
    r = fl.run(SESSIONS, COMMANDS, SIZE, rounds=1)
    assert r["replies"] == {"refused": SESSIONS * COMMANDS, "ok": 0, "unanswered": 0}
    growth = (r["rss_after_mb"][-1] - r["rss_before_mb"]) * 1e6
    assert growth < BOUND_BYTES, r
    assert r["shmem_after_mb"][-1] <= r["shmem_before_mb"], r  # no peer's segment mapped
    sent = (fl.WARMUP_SESSIONS + SESSIONS) * COMMANDS
    assert r["refused_log_lines"] + r["refusals_in_summaries"] == sent  # each logged or counted, once
    assert r["daemon_exit"] == 0
