"""hystbench's benchmarks: each ``bench_NAME`` module has ``main(argv) -> exit status`` and is run by
``hystbench bench NAME [ARGS]``, ``python -m benchmarks.bench_NAME [ARGS]`` or ``python
benchmarks/bench_NAME.py [ARGS]``.  An installed package of the source checkout (``make test``'s
editable install), so the command line and the tests import it, never load a file by its path."""

from __future__ import annotations

import importlib
import pkgutil
from types import ModuleType

__all__ = ["names", "load", "HYSTBENCH_BENCHMARKS"]

#: Tells ``hystbench bench`` that a ``benchmarks`` package on the path is this one.
HYSTBENCH_BENCHMARKS = True


def names() -> list[str]:
    """The benchmarks' NAMEs (modules ``bench_NAME`` of this package), sorted."""
    return sorted(m.name.removeprefix("bench_") for m in pkgutil.iter_modules(__path__) if m.name.startswith("bench_"))


def load(name: str) -> ModuleType:
    """The module of benchmark ``name``; ``LookupError`` naming the known ones if there is none."""
    known = names()
    if name not in known:
        raise LookupError(f"no benchmark {name!r}; known: {', '.join(known) or 'none'}")
    return importlib.import_module(f"{__name__}.bench_{name}")
