"""MCAP logs: the recorder (one log per session, small chunks, rotation), readers, recovery.

- :class:`McapRecorder` — ``start`` -> ``add_block`` / ``add_message`` -> ``finish``; a context manager.
- :func:`iter_blocks`, :func:`iter_log`, :func:`log_metadata`, :class:`McapSource` — replay.
- :func:`segments` — a log's blocks by operating point (:class:`Segment`, each as a recording); the
  log as the live estimator saw it (settling left out) is :mod:`hystbench.analysis.log_recordings`.
- :func:`recover` — salvage every complete chunk of a log whose writer was killed or whose bytes
  were damaged (it resynchronises on the next valid record: :mod:`.resync`); chunks are decoded in
  bounded memory by :mod:`.chunks`.
- :mod:`.schemas` — topics and JSON schemas (documented in docs/pipeline.md); raw blocks are the
  JSON framing of :mod:`hystbench.formats.raw_block`.
"""

from .reader import (LogMessage, McapSource, Segment, estimation_settings, iter_blocks, iter_log, log_metadata,
                     segments)
from .recorder import COMPRESSIONS, McapRecorder
from .recover import RecoverReport, Skipped, recover
from .schemas import COMPENSATOR, ESTIMATE, RAW, STATS, STATUS, TOPICS

__all__ = ["McapRecorder", "COMPRESSIONS", "segments", "Segment", "iter_blocks", "iter_log", "log_metadata",
           "estimation_settings",
           "LogMessage", "McapSource", "recover", "RecoverReport", "Skipped",
           "RAW", "ESTIMATE", "COMPENSATOR", "STATUS", "STATS", "TOPICS"]
