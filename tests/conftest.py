"""What every test shares: tests/ on sys.path, so any test imports the independent bench as
``independent_bench`` (the suite runs with --import-mode=importlib, which adds nothing to sys.path
itself); loggers left as the test found them.

import-linter's command line (tests/test_architecture.py, tests/independent_bench) configures
logging with ``dictConfig``, which disables every logger that exists at that moment, hystbench's
included; every later test that looks for a log record (``caplog``) then finds none."""

from __future__ import annotations

import logging
import sys
from pathlib import Path

import pytest

_TESTS = str(Path(__file__).resolve().parent)
if _TESTS not in sys.path:
    sys.path.insert(0, _TESTS)


@pytest.fixture(autouse=True)
def _loggers_kept():
    loggers = [lg for lg in logging.Logger.manager.loggerDict.values() if isinstance(lg, logging.Logger)]
    disabled = {lg: lg.disabled for lg in loggers}
    yield
    for lg, was in disabled.items():
        lg.disabled = was
