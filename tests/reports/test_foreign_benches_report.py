"""python -m hystbench.reports.foreign_benches: a row per bench, with figures that follow from the bench
(the coil leg's B about the magnet's bias, the force range of the magnet's pull)."""

from __future__ import annotations

from hystbench.reports.foreign_benches import main, operating_point
from hystbench.sim_backend.benches import FOREIGN_BENCHES, bench_truth, foreign_preset


def test_the_table_has_a_row_per_bench(capsys):
    assert main([]) == 0
    out = capsys.readouterr().out
    assert all(f"| {name} |" in out for name in ["ecore_pm", "ecore", *FOREIGN_BENCHES])


def test_an_operating_point_sits_about_the_bench_truth():
    name = "ecore_pm~m130"
    truth = bench_truth(name)
    r = operating_point(foreign_preset(name), 1.4)
    # the coil-leg B swings about the magnet's bias (the ideal-iron one, within the iron's few-% drop)
    mid = (r["b_leg_min_t"] + r["b_leg_max_t"]) / 2
    assert abs(mid / truth["bias_flux_density_t"] - 1) < 0.05
    k0 = truth["force_coefficients"][0]  # the force at zero current lies inside the force range
    assert r["force_min_n"] < k0 < r["force_max_n"] and r["theta_hyst_deg"] > 0
