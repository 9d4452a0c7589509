"""Retention of a bench's MCAP logs: the oldest parts go first, never the one being written.

A daemon left running writes a part every ``rotate_minutes``; without a bound its folder grows
until the disk is full.  :func:`apply_retention` deletes, oldest first (by modification time,
i.e. when the part was last written), the parts of one bench's logs that are older than
``keep_days`` and then as many as needed to bring the total under ``max_total_bytes``.  It only
touches files named as the daemon names its logs (``<bench>-YYYYMMDD-HHMMSS[.k][-NNNN].mcap``), so
other benches' logs, recovered copies and exports in the same folder are left alone; the part(s)
given in ``keep`` (the open one) are never deleted, nor is a part that is not finished (no MCAP
footer) and was written in the last ``UNFINISHED_GRACE_S`` (another process may be writing it),
unless it is one of ``own`` (this process wrote and closed it: a part left without its summary by
a full disk).
"""

from __future__ import annotations

import logging
import re
import stat
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterable

__all__ = ["apply_retention", "RetentionReport", "bench_logs", "UNFINISHED_GRACE_S"]

log = logging.getLogger("hystbench.retention")

MAGIC = b"\x89MCAP0\r\n"  # an MCAP file starts and, once finished, ends with this
#: An unfinished part modified this recently may be another writer's open part.
UNFINISHED_GRACE_S = 600.0


@dataclass
class RetentionReport:
    """What one pass deleted (paths, bytes) and what the bench's logs hold afterwards."""

    deleted: list[Path] = field(default_factory=list)
    deleted_bytes: int = 0
    kept: int = 0
    kept_bytes: int = 0
    errors: list[str] = field(default_factory=list)

    def message(self) -> str:
        return (f"deleted {len(self.deleted)} old log part(s), {self.deleted_bytes / 2**20:.1f} MiB; "
                f"{self.kept} part(s), {self.kept_bytes / 2**20:.1f} MiB kept")


def bench_logs(folder: Path, bench: str) -> list[Path]:
    """The parts of ``bench``'s logs in ``folder`` (its naming only), oldest first."""
    pattern = re.compile(rf"{re.escape(bench)}-\d{{8}}-\d{{6}}(\.\d+)?(-\d{{4}})?\.mcap")
    try:
        names = [p for p in folder.iterdir() if pattern.fullmatch(p.name)]
    except FileNotFoundError:
        return []
    found = []
    for p in names:  # one stat each: a part deleted meanwhile (another daemon's retention) is left out
        try:
            st = p.stat()
        except FileNotFoundError:
            continue
        if stat.S_ISREG(st.st_mode):
            found.append((st.st_mtime, p.name, p))
    return [p for _, _, p in sorted(found)]


def _finished(path: Path) -> bool:
    try:
        with open(path, "rb") as fh:
            fh.seek(-len(MAGIC), 2)
            return fh.read() == MAGIC
    except OSError:
        return False


def apply_retention(folder: str | Path, bench: str, *, keep_days: float = 0.0, max_total_bytes: float = 0.0,
                    keep: Iterable[Path] = (), own: Iterable[Path] = (), now: float | None = None) -> RetentionReport:
    """Delete the oldest parts of ``bench``'s logs in ``folder``: those older than ``keep_days``
    (0: no age limit), then the oldest until the total is at most ``max_total_bytes`` (0: no size
    limit).  ``keep``: parts never deleted (the open one)."""
    now = time.time() if now is None else now
    protected = {Path(p).resolve() for p in keep}
    closed = {Path(p).resolve() for p in own} - protected
    parts = []
    for p in bench_logs(Path(folder), bench):
        try:
            st = p.stat()
        except FileNotFoundError:
            continue
        busy = p.resolve() in protected or (p.resolve() not in closed and now - st.st_mtime < UNFINISHED_GRACE_S
                                            and not _finished(p))
        parts.append((p, st.st_size, st.st_mtime, busy))
    rep = RetentionReport()
    total = sum(size for _, size, _, _ in parts)
    for p, size, mtime, busy in parts:  # oldest first
        too_old = keep_days > 0 and now - mtime > keep_days * 86_400
        too_much = max_total_bytes > 0 and total > max_total_bytes
        if busy or not (too_old or too_much):
            rep.kept += 1
            rep.kept_bytes += size
            continue
        try:
            p.unlink()
        except FileNotFoundError:
            pass
        except OSError as err:
            rep.errors.append(f"{p}: {err.strerror}")
            rep.kept += 1
            rep.kept_bytes += size
            continue
        rep.deleted.append(p)
        rep.deleted_bytes += size
        total -= size
    if rep.deleted:
        log.info("retention in %s: %s", folder, rep.message())
    return rep
