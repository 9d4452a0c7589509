"""hystbench's benchmarks: the speed, memory and acceptance figures of docs/performance.md.

Each ``bench_NAME`` module has ``main(argv) -> exit status``.  Run one from the checkout's root with
``python -m benchmarks NAME [ARGS]`` (``python -m benchmarks`` lists them).  They live beside the
package, not in it: they use the tests' independent bench and are no part of an installed hystbench.
"""

from __future__ import annotations

import importlib
import pkgutil
from types import ModuleType

__all__ = ["names", "load"]


def names() -> list[str]:
    """The benchmarks' NAMEs (modules ``bench_NAME`` of this package), sorted."""
    return sorted(m.name.removeprefix("bench_") for m in pkgutil.iter_modules(__path__) if m.name.startswith("bench_"))


def load(name: str) -> ModuleType:
    """The module of benchmark ``name``; ``LookupError`` naming the known ones if there is none."""
    known = names()
    if name not in known:
        raise LookupError(f"no benchmark {name!r}; known: {', '.join(known) or 'none'}")
    return importlib.import_module(f"{__name__}.bench_{name}")
