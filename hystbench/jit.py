"""The one switch between compiled kernels (numba) and the pure-numpy code they must equal.

The hot per-sample recursions (the Preisach iron, the eddy currents, the force filter, the COBS
codec) have two implementations: a numpy one, which is the reference and the readable statement of
the physics or the protocol, and a numba kernel beside it, which gives the same numbers and is what
runs when numba is installed.  ``HYSTBENCH_JIT=0`` in the environment forces the numpy path, so
every test of a kernel can compare it against its reference in one process, and a machine without
numba loses speed, never a result.

    from hystbench.jit import njit, enabled
    @njit(cache=True, nogil=True)
    def _kernel(x): ...
    run = _kernel if enabled() else _numpy_version

``njit`` compiles lazily (on the first call), so importing a module that declares a kernel costs
nothing until the kernel runs; numba itself is imported on the first ``njit``/``enabled`` call.
Vocabulary layer: standard library only (numba is imported, never required).
"""

from __future__ import annotations

import functools
import hashlib
import os
from pathlib import Path
from typing import Any, Callable

__all__ = ["enabled", "njit", "drop_stale_cache", "ENV"]

ENV = "HYSTBENCH_JIT"


@functools.cache
def _numba() -> Any:
    """numba's module, or None when it is missing or switched off."""
    if os.environ.get(ENV, "1").strip().lower() in ("0", "false", "no", "off"):
        return None
    try:
        import numba
    except ImportError:
        return None
    return numba


def enabled() -> bool:
    """True when compiled kernels run (numba importable and ``HYSTBENCH_JIT`` not 0)."""
    return _numba() is not None


def njit(**options: Any) -> Callable[[Callable], Callable]:
    """``numba.njit(**options)`` when numba runs, else the function itself (plain Python).

    The plain-Python function is never the fallback on a hot path (a loop per sample in
    Python is a bug): callers pick their numpy implementation when ``enabled()`` is False.
    It is returned so a kernel can still be called and tested for its logic without numba.
    """
    numba = _numba()
    if numba is None:
        return lambda function: function
    return numba.njit(**options)


def drop_stale_cache(module_file: str, *dependencies: str) -> None:
    """Remove numba's on-disk cache of ``module_file``'s kernels when ``dependencies`` (files whose jitted
    helpers they inline) changed since it was written.

    numba keys a cached kernel on the file that defines it alone: after an edit of a helper in another
    module it would load the old compiled copy.  Called at the dependent module's import, this keeps a
    digest of the dependencies beside the cache (``__pycache__/<module>.deps``); when it differs, the
    module's cache files (``<module>.*.nbi``/``.nbc``) go and numba compiles afresh.  A cache folder that
    cannot be written is left as it is (an installed package's files change together)."""
    if _numba() is None:
        return
    src = Path(module_file)
    cache = src.parent / "__pycache__"
    stamp = cache / f"{src.stem}.deps"
    try:
        digest = hashlib.sha256(b"".join(Path(d).read_bytes() for d in dependencies)).hexdigest()
        if stamp.is_file() and stamp.read_text() == digest:
            return
        for stale in [*cache.glob(f"{src.stem}.*.nbi"), *cache.glob(f"{src.stem}.*.nbc")]:
            stale.unlink(missing_ok=True)
        cache.mkdir(exist_ok=True)
        stamp.write_text(digest)
    except OSError:
        pass
