"""The independent bench stays independent: only numpy, scipy and the standard library."""

from __future__ import annotations

import ast
import configparser
import sys
from pathlib import Path

from importlinter.cli import lint_imports

PACKAGE = Path(__file__).resolve().parent
ALLOWED_THIRD_PARTY = {"numpy", "scipy"}


def _bench_sources() -> list[Path]:
    """The package's own modules (its tests may import hystbench to read what it writes)."""
    return sorted(p for p in PACKAGE.glob("*.py") if not p.name.startswith(("test_", "conftest")))


def test_the_package_imports_only_numpy_scipy_and_the_standard_library():
    bad = []
    for path in _bench_sources():
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                if node.level:  # relative: inside the package
                    continue
                names = [node.module or ""]
            else:
                continue
            for name in names:
                top = name.split(".")[0]
                if top not in ALLOWED_THIRD_PARTY and top not in sys.stdlib_module_names:
                    bad.append(f"{path.name}:{node.lineno}: {name}")
    assert bad == []
    assert len(_bench_sources()) >= 5  # the check saw the modules


def test_the_contract_names_every_module_of_the_bench():
    """A new module cannot escape the contract by being left out of it."""
    ini = configparser.ConfigParser()
    ini.read(PACKAGE / "importlinter.ini")
    listed = set(ini["importlinter:contract:independent-bench"]["source_modules"].split())
    modules = {f"independent_bench.{p.stem}" for p in _bench_sources() if p.stem != "__init__"}
    assert listed == modules


def test_import_linter_contract_holds(capsys):
    status = lint_imports(config_filename=str(PACKAGE / "importlinter.ini"), no_cache=True)
    report = capsys.readouterr().out
    assert status == 0, report
