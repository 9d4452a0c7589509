"""What every test shares: tests/ and the checkout on sys.path, so any test imports the independent
bench as ``independent_bench`` and the benchmarks as ``benchmarks`` (the suite runs with
--import-mode=importlib, which adds nothing to sys.path itself); loggers left as the test found
them; costly inputs computed once per run (``computed_once``) however many workers ``make test``
starts.

import-linter's command line (tests/test_architecture.py, tests/independent_bench) configures
logging with ``dictConfig``, which disables every logger that exists at that moment, hystbench's
included; every later test that looks for a log record (``caplog``) then finds none."""

from __future__ import annotations

import fcntl
import logging
import os
import sys
from pathlib import Path
from typing import Callable

import pytest

_TESTS = str(Path(__file__).resolve().parent)
_ROOT = str(Path(__file__).resolve().parents[1])  # the checkout: ``benchmarks`` beside the package
for _path in (_TESTS, _ROOT):
    if _path not in sys.path:
        sys.path.insert(0, _path)


@pytest.fixture(autouse=True)
def _loggers_kept():
    loggers = [lg for lg in logging.Logger.manager.loggerDict.values() if isinstance(lg, logging.Logger)]
    disabled = {lg: lg.disabled for lg in loggers}
    yield
    for lg, was in disabled.items():
        lg.disabled = was


@pytest.fixture(scope="session")
def computed_once(tmp_path_factory) -> Callable[[str, Callable[[Path], object]], Path]:
    """``computed_once(name, make)``: the path of file ``name``, which ``make(path)`` writes the first
    time any worker of this run asks (the others wait on its lock, then read it).  For inputs that
    take many seconds to compute and that several test files read (a fitted model file): under
    pytest-xdist a session fixture is otherwise computed once per worker."""
    base = tmp_path_factory.getbasetemp()
    shared = base.parent if os.environ.get("PYTEST_XDIST_WORKER") else base  # one folder per run

    def get(name: str, make: Callable[[Path], object]) -> Path:
        path = shared / name
        with open(shared / f"{name}.lock", "w") as lock:
            fcntl.flock(lock, fcntl.LOCK_EX)  # released when the file closes, also on an error
            if not path.exists():
                make(path)
        return path

    return get


@pytest.fixture(scope="session")
def model_file_of(computed_once) -> Callable[[str], Path]:
    """``model_file_of(rig)``: the model file of a simulated E-core rig, identified from its fit sweep
    (``quick_models``: 40, 160, 480 Hz x 0.3-1.5 A-pp) once per run."""
    from hystbench.compensator.sweeps import quick_models

    return lambda rig: computed_once(f"models_{rig}.json", lambda path: quick_models(rig).save(path))


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """Files run longest first, by their ``slow(seconds)`` marker (stable otherwise): ``make test``
    hands whole files to its workers in this order, and a long file that came last kept one worker
    busy while the others idled (the longest-first rule of scheduling jobs on machines)."""
    seconds: dict = {}
    for item in items:
        mark = item.get_closest_marker("slow")
        if mark is not None:
            seconds[item.path] = max(seconds.get(item.path, 0.0), float(mark.args[0]) if mark.args else 20.0)
    items.sort(key=lambda item: -seconds.get(item.path, 0.0))
