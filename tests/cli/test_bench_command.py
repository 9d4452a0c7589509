"""``hystbench bench NAME`` runs the installed module ``benchmarks.bench_NAME`` (the benchmarks are a
package of their own, installed by ``make test``'s editable install), never a file found by path."""

from __future__ import annotations

import importlib
import subprocess
import sys

from hystbench.cli.main import main


def test_bench_runs_the_importable_module(monkeypatch):
    module = importlib.import_module("benchmarks.bench_sim")
    calls = []
    monkeypatch.setattr(module, "main", lambda argv: calls.append(argv) or 0)  # the run itself takes minutes
    assert main(["bench", "sim", "--seconds", "1", "--json"]) == 0
    assert calls == [["--seconds", "1", "--json"]]  # the module the package holds, not a copy loaded by path


def test_an_unknown_benchmark_is_one_line_naming_the_known_ones(capsys):
    assert main(["bench", "no_such"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("hystbench bench: error: no benchmark 'no_such'; known: ")
    for name in ("compensator", "csv", "estimator", "idle_log", "learning_bench", "pipeline", "sim"):
        assert name in err
    assert "\n" not in err and "Traceback" not in err


def test_installed_for_any_working_directory(tmp_path):
    """From a folder outside the checkout (``-m`` puts that folder on the path, not the checkout):
    the benchmark still imports, as a fresh clone has it after ``make test``."""
    out = subprocess.run([sys.executable, "-m", "hystbench", "bench", "estimator", "--help"], cwd=tmp_path,
                         capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert "usage: hystbench bench estimator" in out.stdout
