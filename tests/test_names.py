"""One spelling per quantity in hystbench's names (issue 30).

A sample rate is ``fs_hz`` and a frequency in Hz is ``frequency_hz`` (or a name for what it is:
``corner_hz``, ``resonance_hz``, ``line_hz``); ``fs``, ``freq_hz`` and ``f_hz`` were the same things
spelt three more ways.  The check walks the source with ``ast`` (no import, so no side effect) and
refuses those spellings as the name of

- a parameter of any function or method (private helpers too: they cross module boundaries, and a
  keyword call should not have to guess which spelling a helper took);
- a class-level field (dataclass, NamedTuple, annotated or assigned class attribute);
- an attribute set on an instance (``self.fs = ...``).

Local variables inside a body (``fs = rec.fs_hz`` before a formula) are left alone, as are keyword
arguments to other libraries (``scipy.signal.butter(..., fs=...)``), wire and file keys
(``frequency_Hz``, ``sample_rate_Hz``) and CLI options (``--fs``, whose argparse attribute is
``args.fs``).
"""

from __future__ import annotations

import ast
from pathlib import Path

import hystbench

PACKAGE = Path(hystbench.__file__).resolve().parent
ROOT = PACKAGE.parent

#: The spellings issue 30 retired, each with the one that replaces it.
RETIRED = {"fs": "fs_hz", "freq_hz": "frequency_hz", "f_hz": "frequency_hz"}

#: Names kept on purpose, as offenders() words them without the line and the advice, e.g.
#: "hystbench/x.py:Fit.method() parameter fs"; empty: every one was renamed.
EXCEPTIONS: frozenset[str] = frozenset()


def _offenders_in(tree: ast.AST) -> list[tuple[int, str, str]]:
    """(line, where, name) of every retired spelling used as a parameter, field or attribute."""
    found = []

    def walk(node: ast.AST, scope: str) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.ClassDef):
                inner = f"{scope}{child.name}"
                for stmt in child.body:
                    targets = []
                    if isinstance(stmt, ast.AnnAssign):
                        targets = [stmt.target]
                    elif isinstance(stmt, ast.Assign):
                        targets = stmt.targets
                    for t in targets:
                        if isinstance(t, ast.Name) and t.id in RETIRED:
                            found.append((stmt.lineno, f"{inner} field", t.id))
                walk(child, inner + ".")
                continue
            if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef)):
                inner = f"{scope}{child.name}"
                a = child.args
                for arg in a.posonlyargs + a.args + a.kwonlyargs + [x for x in (a.vararg, a.kwarg) if x]:
                    if arg.arg in RETIRED:
                        found.append((child.lineno, f"{inner}() parameter", arg.arg))
                walk(child, inner + ".")
                continue
            if isinstance(child, (ast.Assign, ast.AnnAssign, ast.AugAssign)):
                targets = child.targets if isinstance(child, ast.Assign) else [child.target]
                for t in targets:
                    for sub in ast.walk(t):  # self.a, self.fs = ... too
                        if (isinstance(sub, ast.Attribute) and sub.attr in RETIRED
                                and isinstance(sub.value, ast.Name) and sub.value.id in ("self", "cls")):
                            found.append((child.lineno, f"{scope}{sub.value.id} attribute", sub.attr))
            walk(child, scope)

    walk(tree, "")
    return found


def offenders() -> list[str]:
    """path:line: where name (-> the spelling to use) for every retired spelling in the package."""
    out = []
    for path in sorted(PACKAGE.rglob("*.py")):
        rel = path.relative_to(ROOT)
        tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
        for line, where, name in _offenders_in(tree):
            if f"{rel}:{where} {name}" not in EXCEPTIONS:
                out.append(f"{rel}:{line}: {where} {name} (use {RETIRED[name]})")
    return out


def test_no_parameter_field_or_attribute_spells_a_rate_or_frequency_the_retired_way():
    found = offenders()
    assert not found, f"{len(found)} names spelt the retired way (issue 30):\n" + "\n".join(found)


def test_the_check_sees_parameters_fields_and_attributes_and_spares_locals_and_calls():
    source = '''
from dataclasses import dataclass
from typing import NamedTuple

def top(x, fs, *, f_hz=1.0): ...
def fine(x, fs_hz, frequency_hz, corner_hz):
    fs = fs_hz                       # a local: allowed
    return signal.butter(2, 1.0, fs=fs)   # another library's keyword: allowed

@dataclass
class Fit:
    freq_hz: float
    fs_hz: float
    class Inner(NamedTuple):
        fs: float
    def method(self, freq_hz):
        self.f_hz = 1.0
        self.fine_hz = 2.0
        def nested(*, fs): ...
    lambda_ok = lambda fs: fs
'''
    found = sorted((where, name) for _, where, name in _offenders_in(ast.parse(source)))
    assert found == sorted([
        ("top() parameter", "fs"), ("top() parameter", "f_hz"),
        ("Fit field", "freq_hz"), ("Fit.Inner field", "fs"),
        ("Fit.method() parameter", "freq_hz"), ("Fit.method.self attribute", "f_hz"),
        ("Fit.method.nested() parameter", "fs"),
    ])
