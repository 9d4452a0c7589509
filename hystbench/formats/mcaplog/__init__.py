"""MCAP logs: the recorder (one log per session, small chunks, rotation), readers, recovery.

- :class:`McapRecorder` — ``start`` -> ``add_block`` / ``add_message`` -> ``finish``; a context manager.
- :func:`read_mcap_recording`, :func:`read_mcap_segments` — a log as interchange-format recordings.
- :func:`iter_blocks`, :func:`iter_log`, :func:`log_metadata`, :class:`McapSource` — replay.
- :func:`recover` — salvage every complete chunk of a log whose writer was killed.
- :mod:`.schemas` — topics, JSON schemas, the raw-block codec (documented in docs/pipeline.md).
"""

from .reader import (LogMessage, McapSource, iter_blocks, iter_log, log_metadata, read_mcap_recording,
                     read_mcap_segments)
from .recorder import COMPRESSIONS, McapRecorder
from .recover import RecoverReport, recover
from .schemas import COMPENSATOR, ESTIMATE, RAW, STATS, STATUS, TOPICS, decode_block, encode_block

__all__ = ["McapRecorder", "COMPRESSIONS", "read_mcap_recording", "read_mcap_segments", "iter_blocks",
           "iter_log", "log_metadata", "LogMessage", "McapSource", "recover", "RecoverReport",
           "encode_block", "decode_block", "RAW", "ESTIMATE", "COMPENSATOR", "STATUS", "STATS", "TOPICS"]
