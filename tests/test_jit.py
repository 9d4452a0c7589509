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


def test_a_changed_dependency_drops_the_dependent_modules_cache_once(tmp_path):
    """numba keys a cached kernel on its own file: drop_stale_cache removes the module's cache files when
    a file whose helpers it inlines changed, and leaves them while nothing did."""
    from hystbench import jit

    if not jit.enabled():
        pytest.skip("numba missing or HYSTBENCH_JIT=0: no cache to drop")
    module, helper = tmp_path / "kernels.py", tmp_path / "helpers.py"
    module.write_text("# kernels\n")
    helper.write_text("def h(): return 1\n")
    cache = tmp_path / "__pycache__"
    cache.mkdir()
    cached = [cache / "kernels.run-12.py311.nbi", cache / "kernels.run-12.py311.1.nbc"]
    other = cache / "helpers.h-1.py311.nbi"  # another module's cache is not touched

    def fill() -> None:
        for f in (*cached, other):
            f.write_bytes(b"x")

    fill()
    jit.drop_stale_cache(str(module), str(helper))  # no digest kept yet: the cache cannot be trusted
    assert not any(f.exists() for f in cached) and other.exists()
    fill()
    jit.drop_stale_cache(str(module), str(helper))  # nothing changed: kept
    assert all(f.exists() for f in cached)
    helper.write_text("def h(): return 2\n")
    jit.drop_stale_cache(str(module), str(helper))
    assert not any(f.exists() for f in cached) and other.exists()
