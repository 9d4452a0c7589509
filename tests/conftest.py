"""What every test shares: loggers left as the test found them.

import-linter's command line (tests/test_architecture.py, tests/independent_bench) configures
logging with ``dictConfig``, which disables every logger that exists at that moment, hystbench's
included; every later test that looks for a log record (``caplog``) then finds none."""

from __future__ import annotations

import logging

import pytest


@pytest.fixture(autouse=True)
def _loggers_kept():
    loggers = [lg for lg in logging.Logger.manager.loggerDict.values() if isinstance(lg, logging.Logger)]
    disabled = {lg: lg.disabled for lg in loggers}
    yield
    for lg, was in disabled.items():
        lg.disabled = was
