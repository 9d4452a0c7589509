"""What ``hystbench recover`` salvages from a log damaged mid-file (issue 26): 64 random bytes at 40 %.

A ~3.2 MB log is written by the project's recorder (raw blocks of 2000 samples and an estimate
each, zstd chunks of 256 KiB), a copy gets 64 random bytes at 40 % of its length, and ``recover``
salvages the copy.  Run: ``python -m benchmarks recover [--seed 26]``; one JSON line.
"""

from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path

import numpy as np


def write_log(path: Path, size_bytes: int = 3_200_000) -> int:
    """A log of about ``size_bytes``; returns its messages."""
    from hystbench.acquisition.sources import operating_meta
    from hystbench.blocks import SampleBlock
    from hystbench.formats.mcaplog import ESTIMATE, McapRecorder

    fs, n = 100_000.0, 2000
    rng = np.random.default_rng(1)
    meta = {"recording": {"rig": "ecore_pm", "frequency_Hz": 320.0, "sample_rate_Hz": fs, "current_pp_A": 1.4}}
    with McapRecorder(path, metadata=meta, overwrite=True) as rec:
        k = 0
        while rec.bytes_written < size_bytes - 150_000:
            t = (k * n + np.arange(n)) / fs
            ch = {"current_A": 0.7 * np.sin(2 * np.pi * 320 * t) + 1e-3 * rng.standard_normal(n),
                  "force_N": 175 + 45 * np.sin(2 * np.pi * 320 * t - 0.05) + 1e-2 * rng.standard_normal(n),
                  "flux_Wb": 5e-5 * np.sin(2 * np.pi * 320 * t - 0.02) + 1e-8 * rng.standard_normal(n)}
            rec.add_block(SampleBlock(k * n, fs, {c: x.astype(np.float32) for c, x in ch.items()},
                                      meta=operating_meta(320.0, 1.4, 0.0, True)))
            rec.add_message(ESTIMATE, {"first_index": k * n, "end_index": (k + 1) * n}, rec.index_time_ns(k * n, fs))
            k += 1
    return rec.messages


def main(argv: list[str] | None = None) -> int:
    from hystbench.formats.mcaplog import recover

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=26)
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        log, damaged = Path(tmp) / "log.mcap", Path(tmp) / "damaged.mcap"
        messages = write_log(log)
        data = bytearray(log.read_bytes())
        at = int(0.4 * len(data))
        data[at:at + 64] = np.random.default_rng(args.seed).bytes(64)
        damaged.write_bytes(bytes(data))
        rep = recover(damaged)
        print(json.dumps({"log_bytes": len(data), "messages": messages, "damaged_at": at,
                          "bytes_salvaged": rep.bytes_salvaged, "messages_salvaged": rep.messages,
                          "chunks_salvaged": rep.chunks, "chunks_lost": getattr(rep, "chunks_lost", None),
                          "skipped": getattr(rep, "skipped", None)}, default=str))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
