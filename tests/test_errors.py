"""The exception tree is complete and drawn once: every exception class the package defines is a
BenchError, reached through the branch the drawing in ``hystbench/errors.py`` shows.

The classes are found by importing every module of the package (``pkgutil.walk_packages``), so a
new class in a new module cannot be forgotten; the drawing is parsed from the module docstring,
so it cannot drift from the code either way (a class missing from it, or a name in it that no
longer exists, or drawn under the wrong parent).
"""

from __future__ import annotations

import ast
import importlib
import inspect
import pkgutil
import re
from pathlib import Path

import hystbench
from hystbench import errors
from hystbench.errors import BenchError

PACKAGE = Path(hystbench.__file__).resolve().parent


def defined_exceptions() -> dict[str, type]:
    """Every exception class defined at module level (or inside a class) anywhere in hystbench."""
    found: dict[str, type] = {}

    def visit(owner: object, module: str) -> None:
        for obj in vars(owner).values():
            if inspect.isclass(obj) and obj.__module__ == module:
                if issubclass(obj, BaseException):
                    assert obj.__name__ not in found or found[obj.__name__] is obj, \
                        f"two exception classes named {obj.__name__}: {found[obj.__name__]} and {obj}"
                    found[obj.__name__] = obj
                visit(obj, module)

    for info in pkgutil.walk_packages(hystbench.__path__, "hystbench."):
        if info.name.rsplit(".", 1)[-1] == "__main__":  # runs the command line when imported
            continue
        module = importlib.import_module(info.name)
        visit(module, module.__name__)
    return found


def drawn_tree() -> dict[str, str | None]:
    """``{class name: parent name}`` from the drawing in hystbench/errors.py (the root's parent is
    None).  The drawing is the docstring's second paragraph: its first line is the root, every
    other class follows a ``├── `` or ``└── ``, and a class's parent is the nearest class above
    whose name starts in an earlier column; lines without a connector continue a description."""
    lines = errors.__doc__.split("\n\n")[1].splitlines()
    root = re.match(r"\s*(\w+)", lines[0])
    parents: dict[str, str | None] = {root.group(1): None}
    stack = [(root.start(1), root.group(1))]
    for line in lines[1:]:
        m = re.search(r"[├└]── (\w+)", line)
        if m is None:
            continue
        col = m.start(1)
        while stack and stack[-1][0] >= col:
            stack.pop()
        assert stack, f"a class left of the root in the drawing: {line!r}"
        assert m.group(1) not in parents, f"{m.group(1)} drawn twice"
        parents[m.group(1)] = stack[-1][1]
        stack.append((col, m.group(1)))
    return parents


def test_the_drawing_parses_to_a_tree_rooted_at_bench_error():
    tree = drawn_tree()
    assert [name for name, parent in tree.items() if parent is None] == ["BenchError"]
    # spot checks against the drawing as written (an independent reading of the picture)
    assert tree["ConfigError"] == "BenchError" and tree["ListenError"] == "NetworkError"
    assert tree["FrameError"] == "ProtocolError" and tree["LearningStopped"] == "CompensatorError"
    assert tree["CommandRefused"] == "BenchError"


def test_every_exception_class_of_the_package_is_on_the_tree_and_drawn_where_it_is():
    found = defined_exceptions()
    tree = drawn_tree()
    # the classes the issue names are among those found (the walk reaches drivers, compensator, zenoh)
    assert {"ScpiError", "ModbusError", "ChargeAmpError", "IntegratorError", "SafetyLimitError", "LearningStopped",
            "UnreachableReference", "ListenError", "NoReply", "CommandRefused", "FrameError"} <= set(found)
    off_tree = sorted(n for n, c in found.items() if not issubclass(c, BenchError))
    assert off_tree == [], f"not BenchError subclasses: {off_tree}"
    undrawn = sorted(set(found) - set(tree))
    assert undrawn == [], f"missing from the drawing in hystbench/errors.py: {undrawn}"
    stale = sorted(set(tree) - set(found))
    assert stale == [], f"drawn in hystbench/errors.py but defined nowhere: {stale}"
    for name, cls in found.items():
        if cls is BenchError:
            continue
        tree_bases = [b.__name__ for b in cls.__bases__ if issubclass(b, BenchError)]
        assert tree_bases == [tree[name]], f"{name} derives from {tree_bases}, drawn under {tree[name]}"


def test_no_exception_class_hides_inside_a_function():
    """The walk sees module and class level only: an exception class defined in a function body
    would escape it, so there is none."""
    hidden = []
    for path in PACKAGE.rglob("*.py"):
        for fn in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(fn, (ast.FunctionDef, ast.AsyncFunctionDef)):
                for node in ast.walk(fn):
                    if isinstance(node, ast.ClassDef) and any(
                            re.search(r"(Error|Exception|Refused|Reply|Stopped|Lost|Timeout)$", ast.unparse(b))
                            for b in node.bases):
                        hidden.append(f"{path.relative_to(PACKAGE)}:{node.lineno} {node.name}")
    assert hidden == []


def test_a_run_time_refusal_is_not_a_config_error():
    """'a sweep is running' says nothing about the files or options: a handler that catches
    ConfigError to blame the configuration must not see it."""
    from hystbench.errors import CommandRefused, ConfigError, NoReply

    assert not issubclass(CommandRefused, ConfigError) and not issubclass(CommandRefused, ValueError)
    assert not issubclass(NoReply, ConfigError) and issubclass(NoReply, TimeoutError)
    from hystbench.acquisition.zenoh_bus import ListenError

    assert not issubclass(ListenError, ConfigError)


def test_a_script_says_a_bench_error_in_one_line_and_exits_2(capsys):
    from hystbench.errors import RecordingError, script_status

    def bad() -> int:
        raise RecordingError("/x.csv: missing sidecar")

    assert script_status(lambda: 0) == 0
    assert script_status(bad) == 2
    assert capsys.readouterr().err == "error: /x.csv: missing sidecar\n"
