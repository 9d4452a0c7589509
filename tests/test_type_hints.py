"""Every public function and constructor of hystbench says its types (issue 11).

A signature is the first thing a reader (and a type checker) trusts: ``Pipeline(source,
recorder, bus)`` with no hints says nothing of what a source must be. The check walks the
source with ``ast`` (no import, so no side effect and no optional dependency needed) and asks,
for every public module-level function and every public method (``__init__`` included) of a
public class: an annotation on each parameter but ``self``/``cls``, and a return annotation on
all but ``__init__`` (whose return is always ``None``).
"""

from __future__ import annotations

import ast
import importlib
from collections.abc import Iterator
from pathlib import Path

import hystbench

PACKAGE = Path(hystbench.__file__).resolve().parent
ROOT = PACKAGE.parent

FunctionNode = ast.FunctionDef | ast.AsyncFunctionDef


def _is_public(name: str) -> bool:
    return not name.startswith("_") or name == "__init__"


def _public_functions(tree: ast.Module) -> Iterator[tuple[FunctionNode, bool]]:
    """Yield (function, is_method) for the module's public functions and public classes' methods.

    Nested classes count when every class around them is public; functions inside functions
    are implementation detail and do not.
    """

    def walk(body: list[ast.stmt], in_class: bool) -> Iterator[tuple[FunctionNode, bool]]:
        for node in body:
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                if _is_public(node.name) and (in_class or node.name != "__init__"):
                    yield node, in_class
            elif isinstance(node, ast.ClassDef):
                if not node.name.startswith("_"):
                    yield from walk(node.body, True)
            elif isinstance(node, (ast.If, ast.Try)):
                # definitions under `if TYPE_CHECKING:`/`try: import ...` are still module-level
                blocks = [node.body, node.orelse]
                if isinstance(node, ast.Try):
                    blocks += [h.body for h in node.handlers] + [node.finalbody]
                for block in blocks:
                    yield from walk(block, in_class)

    yield from walk(tree.body, False)


def _missing(function: FunctionNode, is_method: bool) -> list[str]:
    """What the signature lacks, in words: the unannotated parameters and/or the return."""
    args = function.args
    positional = args.posonlyargs + args.args
    is_static = any(
        isinstance(d, ast.Name) and d.id == "staticmethod" for d in function.decorator_list
    )
    if is_method and not is_static and positional:
        positional = positional[1:]  # self or cls: its type is the class
    params = positional + args.kwonlyargs + [a for a in (args.vararg, args.kwarg) if a]
    missing = [f"parameter {a.arg}" for a in params if a.annotation is None]
    if function.name != "__init__" and function.returns is None:
        missing.append("return")
    return missing


def offenders() -> list[str]:
    """file:line:name (what is missing) for every public signature without its types."""
    found = []
    for path in sorted(PACKAGE.rglob("*.py")):
        tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
        for function, is_method in _public_functions(tree):
            missing = _missing(function, is_method)
            if missing:
                where = f"{path.relative_to(ROOT)}:{function.lineno}:{function.name}"
                found.append(f"{where} ({', '.join(missing)})")
    return found


def test_every_public_function_and_constructor_has_type_hints():
    found = offenders()
    assert not found, f"{len(found)} public signatures without type hints:\n" + "\n".join(found)


def _check_source(source: str) -> list[str]:
    tree = ast.parse(source)
    return [
        f"{f.name}: {', '.join(m)}"
        for f, is_method in _public_functions(tree)
        if (m := _missing(f, is_method))
    ]


def test_the_check_sees_what_it_must_and_spares_what_it_may():
    """The walker itself: it flags each kind of gap and leaves private and nested code alone."""
    source = '''
def public(x, y: int):
    pass
def _private(x):
    pass
def typed(x: int, *args: str, **kw: float) -> None:
    def inner(z):
        pass
class Pipeline:
    def __init__(self, source, recorder: object):
        pass
    def run(self) :
        pass
    @staticmethod
    def make(a: int):
        pass
    @classmethod
    def build(cls, n: int) -> "Pipeline":
        pass
    def __enter__(self):
        pass
    def _hidden(self, q):
        pass
    class Nested:
        def go(self, v) -> None:
            pass
class _Private:
    def run(self, v):
        pass
def star(*args, **kwargs) -> None:
    pass
'''
    assert _check_source(source) == [
        "public: parameter x, return",
        "__init__: parameter source",
        "run: return",
        "make: return",
        "go: parameter v",
        "star: parameter args, parameter kwargs",
    ]


def _type_checking_imports(tree: ast.Module) -> list[ast.stmt]:
    """The imports under the module's top-level ``if TYPE_CHECKING:``: names only a checker sees."""
    found: list[ast.stmt] = []
    for node in tree.body:
        if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
            found += [n for n in node.body if isinstance(n, (ast.Import, ast.ImportFrom))]
    return found


def unresolved() -> list[str]:
    """file:line:name (annotation: error) for every public hint that names nothing.

    ``from __future__ import annotations`` keeps hints as text that nothing evaluates at run time,
    so a misspelt or unimported type would pass the first test unseen: each hint is evaluated in
    its module's namespace plus the module's ``TYPE_CHECKING`` imports (as a checker reads it)."""
    found = []
    for path in sorted(PACKAGE.rglob("*.py")):
        if path.name == "__main__.py":
            continue  # importing it would run the command line
        parts = path.relative_to(ROOT).with_suffix("").parts
        name = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
        tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
        namespace = dict(vars(importlib.import_module(name)))
        for stmt in _type_checking_imports(tree):
            exec(compile(ast.Module([stmt], []), str(path), "exec"), namespace)  # noqa: S102
        for function, _ in _public_functions(tree):
            args = function.args
            params = args.posonlyargs + args.args + args.kwonlyargs + [a for a in (args.vararg, args.kwarg) if a]
            hints = [a.annotation for a in params if a.annotation is not None]
            hints += [function.returns] if function.returns is not None else []
            for hint in hints:
                text = ast.unparse(hint)
                try:
                    value = eval(text, namespace)  # noqa: S307
                    while isinstance(value, str):  # a quoted forward reference
                        value = eval(value, namespace)  # noqa: S307
                except Exception as err:
                    found.append(f"{path.relative_to(ROOT)}:{function.lineno}:{function.name} "
                                 f"({text}: {type(err).__name__}: {err})")
    return found


def test_every_public_hint_names_a_real_type():
    found = unresolved()
    assert not found, f"{len(found)} hints that name nothing:\n" + "\n".join(found)
