"""Bytes an idle daemon writes to its log (output off), per ``[recording] idle_raw`` policy.

Issue 16: the idle daemon recorded every raw sample, ~380 kB/s (~33 GB a day) with the default
source (the emulated bench, 4 channels at 100 kS/s, zstd).  This runs the daemon's service with
the default configuration except the log folder, zenoh off and ``idle_raw``, waits ``--settle``
seconds, then measures the growth of the log over ``--seconds`` (the recorder's bytes on disk,
compressed).  Run: ``python benchmarks/bench_idle_log.py [--source bench|sim] [--seconds 20]``.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import threading
import time
from pathlib import Path


def measure(source: str, policy: str, seconds: float, settle: float) -> dict:
    from hystbench.service.daemon_config import load_daemon_config
    from hystbench.service.service import BenchService

    with tempfile.TemporaryDirectory() as tmp:
        cfg = Path(tmp) / "daemon.toml"
        cfg.write_text(f'[daemon]\nlog_dir = "{tmp}/logs"\n[source]\nkind = "{source}"\n[zenoh]\nenabled = false\n'
                       f'[recording]\nidle_raw = "{policy}"\n', encoding="utf-8")
        svc = BenchService(load_daemon_config(cfg)).start()
        try:
            threading.Event().wait(settle)
            b0, t0 = svc.recorder.bytes_written, time.monotonic()
            threading.Event().wait(seconds)
            b1, t1 = svc.recorder.bytes_written, time.monotonic()
            skipped = svc.recorder.idle_samples_skipped
        finally:
            svc.stop()
    rate = (b1 - b0) / (t1 - t0)
    return {"source": source, "idle_raw": policy, "bytes_per_s": round(rate), "GB_per_day": round(rate * 86_400 / 1e9, 3),
            "idle_samples_skipped": skipped}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--source", choices=("bench", "sim"), default="bench")
    ap.add_argument("--seconds", type=float, default=20.0)
    ap.add_argument("--settle", type=float, default=3.0)
    ap.add_argument("--policies", default="full,decimated,off")
    args = ap.parse_args(argv)
    for policy in args.policies.split(","):
        print(json.dumps(measure(args.source, policy, args.seconds, args.settle)), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
