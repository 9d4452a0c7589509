"""What the benchmarks that run daemons as subprocesses share."""

from __future__ import annotations

import subprocess

__all__ = ["stop_process"]


def stop_process(proc: subprocess.Popen, hang_s: float) -> int | None:
    """SIGTERM, then SIGKILL if it has not exited within ``hang_s``; its exit status."""
    if proc.poll() is None:
        proc.terminate()
        try:
            proc.wait(hang_s)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(hang_s)
    return proc.returncode
