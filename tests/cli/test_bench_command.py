"""``python -m benchmarks NAME`` runs ``benchmarks.bench_NAME`` from the checkout (the benchmarks live
beside the package, not in it); the tests import the same modules."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from benchmarks.__main__ import main

ROOT = Path(__file__).resolve().parents[2]


def test_a_name_runs_that_module_with_the_rest_of_the_arguments(monkeypatch):
    import benchmarks.bench_sim as module

    calls = []
    monkeypatch.setattr(module, "main", lambda argv: calls.append(argv) or 0)  # the run itself takes minutes
    assert main(["sim", "--seconds", "1", "--json"]) == 0
    assert calls == [["--seconds", "1", "--json"]]


def test_an_unknown_benchmark_is_one_line_naming_the_known_ones(capsys):
    assert main(["no_such"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("python -m benchmarks: error: no benchmark 'no_such'; known: ")
    for name in ("compensator", "csv", "diagnose", "estimator", "idle_log", "learning_bench", "pipeline", "sim"):
        assert name in err
    assert "\n" not in err and "Traceback" not in err


@pytest.mark.parametrize("argv", [[], ["--help"]])
def test_without_a_name_the_benchmarks_are_listed(argv, capsys):
    assert main(argv) == 0
    assert "diagnose" in capsys.readouterr().out


def test_from_the_checkout_as_the_readme_says():
    out = subprocess.run([sys.executable, "-m", "benchmarks", "estimator", "--help"], cwd=ROOT,
                         capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert "usage: python -m benchmarks estimator" in out.stdout


def test_the_benchmarks_are_not_installed_with_the_package():
    import tomllib

    found = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"]["find"]
    assert found["include"] == ["hystbench*"]
