"""A source through the pipeline into one MCAP log, and a log through the same pipeline again.

``hystbench record`` and ``replay`` without the daemon (no zenoh), and what the tests and the
demo record with.  A replay estimates with the settings the log was recorded with (its
``config.estimation`` metadata, settling included), so replay equals live.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, Mapping

from ..errors import BenchError, RecordingError
from ..formats.mcaplog import McapRecorder, McapSource, iter_blocks
from ..formats.outputs import output_file
from .pipeline import Pipeline
from .stages import WindowEstimator

if TYPE_CHECKING:
    from .sources import Source

__all__ = ["record_log", "replay_log", "has_measurement"]

Listener = Callable[[str, dict], None]


def record_log(source: Source, out: str | Path, *, estimation: Mapping[str, float] | None = None,
               compression: str = "zstd", overwrite: bool = False, on_message: Listener | None = None,
               timeout_s: float | None = None) -> dict[str, Any]:
    """Run ``source`` through the pipeline (no zenoh) into one MCAP log; a summary: ``log`` (the
    paths), ``samples``, ``estimates`` (in order), ``bytes``, ``stats``.  Ctrl-C or ``timeout_s``
    stop it; a pipeline failure is a :class:`RecordingError` naming ``out`` (the log could not be
    written to its end), the stage's error its ``__cause__``."""
    settings = {"periods": 10.0, "settle_periods": 2.0, **(estimation or {})}
    est = WindowEstimator(source.fs_hz, source.metadata(), **settings)
    settings["settle_s"] = est.settle_s  # what the live run skipped after each change: replays skip the same
    meta = {"recording": source.metadata(), "config": {"estimation": settings, "source": source.name}}
    rig = getattr(getattr(source, "rig", None), "preset", None)
    if rig:
        meta["rig"] = {k: v for k, v in rig.items() if not k.startswith("_")}
    with McapRecorder(out, metadata=meta, compression=compression, overwrite=overwrite) as rec:
        pipe = Pipeline(source, estimator=est, recorder=rec)
        estimates = _run_collecting(pipe, on_message, timeout_s, f"{out}: recording failed")
    if pipe.log_error is not None:  # the disk's fault: the run went on, the log stopped (not a success)
        raise RecordingError(f"{out}: the log stopped after {pipe.stats['record'].samples} of "
                             f"{pipe.stats['source'].samples} samples ({pipe.log_error}); `hystbench recover {out}` "
                             "salvages its complete chunks")
    return {"log": [str(p) for p in rec.paths], "samples": pipe.stats["source"].samples, "estimates": estimates,
            "bytes": sum(Path(p).stat().st_size for p in rec.paths), "stats": pipe.stats_dict()}


def replay_log(path: str | Path, *, speed: str = "max", out: str | Path | None = None,
               on_message: Listener | None = None, overwrite: bool = False,
               prepare: Callable[[Pipeline], None] | None = None) -> list[dict]:
    """Feed a log through the same pipeline (estimation settings from the log); the estimates.
    With ``out``, the replay is itself recorded.  ``prepare`` gets the pipeline before it starts
    (a live view attaches to it and waits for its client there; not with ``out``).  A failure is a
    :class:`RecordingError` naming ``path`` (or ``out``)."""
    if out is not None:
        if prepare is not None:
            raise ValueError("replay_log: prepare is not for a recorded replay")
        # all or nothing, unlike a recording (whose log is the measurement, kept as far as it got): a
        # replay that fails leaves no part of a log, and a log it replaces stays until it succeeds
        with output_file(out, overwrite=overwrite, inputs=[path]) as tmp:
            src = McapSource(path, pace="realtime" if speed == "realtime" else "max")
            return record_log(src, tmp, estimation=src.estimation, overwrite=True,
                              on_message=on_message)["estimates"]
    src = McapSource(path, pace="realtime" if speed == "realtime" else "max")
    est = WindowEstimator(src.fs_hz, src.metadata(), **src.estimation)
    pipe = Pipeline(src, estimator=est, dtype=src.dtype)
    if prepare is not None:
        prepare(pipe)
    return _run_collecting(pipe, on_message, None, f"{path}: replay failed")


def has_measurement(log: str | Path) -> bool:
    """Whether ``log`` holds any sample taken with the output on (a bench's idle samples before the
    first command are no measurement); an unreadable log counts as holding one, so that nothing
    that may hold data is ever deleted on its strength (``hystbench recover`` salvages it)."""
    try:
        return any(b.point is None or b.point.output_on for b in iter_blocks(log))  # no meta: on
    except BenchError:
        return True


def _run_collecting(pipe: Pipeline, on_message: Listener | None, timeout_s: float | None, failure: str) -> list[dict]:
    """Run the pipeline to its end (Ctrl-C or ``timeout_s`` stop it); its estimates, in order."""
    estimates: list[dict] = []
    pipe.listeners.append(lambda t, o: estimates.append(dict(o)) if t == "/estimate" else None)
    if on_message is not None:
        pipe.listeners.append(on_message)
    try:  # a Ctrl-C while the threads start stops them too, before the caller closes the log under them
        pipe.start()
        if not pipe.join(timeout_s):
            pipe.stop()
    except KeyboardInterrupt:
        pipe.stop()
    if pipe.error is not None:
        raise RecordingError(f"{failure}: {pipe.error}") from pipe.error
    return estimates
