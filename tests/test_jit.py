"""The jit switch: HYSTBENCH_JIT=0 gives the numpy path; otherwise numba compiles when installed."""

from __future__ import annotations

import subprocess
import sys

import pytest

PROBE = "from hystbench import jit; print(jit.enabled()); f = jit.njit()(lambda x: x + 1); print(type(f).__name__)"


def _probe(env_value: str | None) -> list[str]:
    import os

    env = dict(os.environ)
    env.pop("HYSTBENCH_JIT", None)
    if env_value is not None:
        env["HYSTBENCH_JIT"] = env_value
    out = subprocess.run([sys.executable, "-c", PROBE], env=env, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    return out.stdout.split()


@pytest.mark.parametrize("value", ["0", "off", "false"])
def test_switched_off_gives_plain_functions(value):
    assert _probe(value) == ["False", "function"]


def test_default_compiles_with_numba():
    pytest.importorskip("numba")
    assert _probe(None) == ["True", "CPUDispatcher"]
