"""Puts tests/ on sys.path so the tests import the bench as ``independent_bench`` (the suite runs
with --import-mode=importlib, which adds nothing to sys.path itself)."""

import sys
from pathlib import Path

_TESTS = str(Path(__file__).resolve().parents[1])
if _TESTS not in sys.path:
    sys.path.insert(0, _TESTS)
