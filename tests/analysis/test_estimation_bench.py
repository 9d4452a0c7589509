"""Smoke test of the estimator benchmark (the Monte-Carlo run itself is ``benchmarks/bench_estimator.py``),
imported as the installed module it is."""

from __future__ import annotations

import importlib
import json

import pytest


@pytest.fixture(scope="module")
def bench():
    return importlib.import_module("benchmarks.bench_estimator")


def test_run_reports_one_cell_per_grid_point(bench):
    result = bench.run(trials=60, snr_db=(40.0,), periods=(2, 10))
    assert [(c["snr_db"], c["periods"], c["n"]) for c in result["cells"]] == [(40.0, 2, 63), (40.0, 10, 313)]
    for cell in result["cells"]:
        assert cell["converged"] == 60
        # 60 trials know the RMS to ~9 %: loose bounds, the real check is the benchmark
        assert 0.7 < cell["ratio"] < 1.4
        # the covariance method is quantised: 0.37 of a sample (37 us) off at this delay
        assert cell["rms_cov_s"] > 30e-6
    assert result["config"]["delay_s"] == pytest.approx(2.37e-4)


def test_main_prints_json(bench, capsys, monkeypatch):
    monkeypatch.setattr(bench, "SNR_DB", (60.0,))  # one small cell, not the full grid
    monkeypatch.setattr(bench, "PERIODS", (10,))
    code = bench.main(["--json", "--trials", "30", "--seed", "3"])
    out = json.loads(capsys.readouterr().out)
    assert code in (0, 1) and code == (0 if out["all_pass"] else 1)
    assert out["config"]["trials"] == 30 and out["config"]["seed"] == 3
    assert len(out["cells"]) == 1


def test_main_prints_a_table(bench, capsys, monkeypatch):
    monkeypatch.setattr(bench, "SNR_DB", (60.0,))
    monkeypatch.setattr(bench, "PERIODS", (2,))
    bench.main(["--trials", "20"])
    out = capsys.readouterr().out
    assert "RMS/√CRLB" in out and "RMS(cov)" in out
    assert out.count("pass") + out.count("FAIL") >= 2  # the cell and the verdict line
