"""The house's rules hold: imports point down the layers of docs/architecture.md (.importlinter)."""

from __future__ import annotations

import configparser
import pkgutil
import re
from pathlib import Path

import hystbench
from importlinter.cli import lint_imports

ROOT = Path(__file__).resolve().parents[1]
CONFIG = ROOT / ".importlinter"


def test_imports_point_down_the_layers(capsys):
    status = lint_imports(config_filename=str(CONFIG), no_cache=True)
    report = capsys.readouterr().out
    assert status == 0, report[report.find("Broken contracts"):]


def test_every_module_of_the_package_has_a_layer():
    """A new top-level module or package cannot escape the rules by being left out of them."""
    ini = configparser.ConfigParser()
    ini.read(CONFIG)
    layered = set(re.findall(r"hystbench\.(\w+)", ini["importlinter:contract:layers"]["layers"]))
    top = {m.name for m in pkgutil.iter_modules(hystbench.__path__)} - {"__main__"}
    assert top - layered == set()
