"""Locating the mismatch on constructed residual tables whose answer is known by hand."""

from __future__ import annotations

import json
import math

import pytest

from hystbench.analysis.diagnosis.locate import ResidualEntry, chi2_z, locate

FREQS = (40.001, 120.003, 480.0)


def _table(hot: float = 202.0, start: bool = True) -> list[ResidualEntry]:
    """Three ecore_pm records x two views x harmonics 0..3 + one mains line, every cell at its
    expectation (chi2 = dof = 2) but record 1's force vs flux harmonic 0 (chi2 = ``hot``)."""
    out = []
    for r, f in enumerate(FREQS):
        t = 10.0 * r if start else None
        for ch, view in (("flux_Wb", "flux vs current"), ("force_N", "force vs flux")):
            for k in range(4):
                chi2 = hot if (r, view, k) == (1, "force vs flux", 0) else 2.0
                out.append(ResidualEntry(r, "ecore_pm", f, 1.4, t, ch, view, str(k), chi2, 2))
        out.append(ResidualEntry(r, "ecore_pm", f, 1.4, t, "force_N", "alone", "line 50 Hz", 1.0, 1))
    return out


def test_the_hot_cell_comes_first_with_its_z_by_hand():
    located = locate(_table())
    top = located.top(3)
    assert (top[0]["view"], top[0]["harmonic"], top[0]["rig"]) == ("force vs flux", "0", "ecore_pm")
    # The cell view x harmonic x rig sums the three records: chi2 = 202 + 2 + 2, dof = 6.
    assert top[0]["z"] == pytest.approx((206 - 6) / math.sqrt(12), abs=1e-3)
    assert top[0]["text"] == "force vs flux, harmonic 0, ecore_pm: z = 57.7"
    assert all(t["z"] == pytest.approx(0.0) for t in top[1:])
    summary = located.to_json()
    harmonic_0 = summary["harmonics"][0]
    assert harmonic_0["label"] == "0"
    assert harmonic_0["z"] == pytest.approx((212 - 12) / math.sqrt(24), abs=1e-3)  # 6 cells, one hot
    assert (harmonic_0["chi2"], harmonic_0["dof"]) == (212.0, 12)


def test_axes_are_sorted_as_a_reader_expects():
    summary = locate(_table()).to_json()
    assert set(summary) == {"channels", "harmonics", "frequencies_Hz", "amplitudes_pp_A", "rigs", "time"}
    assert [c["label"] for c in summary["channels"]] == ["flux vs current", "force vs flux", "force_N alone"]
    assert [h["label"] for h in summary["harmonics"]] == ["0", "1", "2", "3", "line 50 Hz"]
    assert [f["value"] for f in summary["frequencies_Hz"]] == [40.0, 120.0, 480.0]
    hot_f = max(summary["frequencies_Hz"], key=lambda c: c["z"])
    assert hot_f["value"] == 120.0  # the hot record's frequency
    assert hot_f["z"] == pytest.approx((202 + 7 * 2 + 1 - 17) / math.sqrt(34), abs=1e-3)
    assert [a["value"] for a in summary["amplitudes_pp_A"]] == [1.4]
    assert [r["label"] for r in summary["rigs"]] == ["ecore_pm"]


def test_a_trend_along_the_sweep_scores_and_a_uniform_excess_does_not():
    """Four records at t = 0, 1, 2, 3 s, dof 2 each, excess 10 t: the weighted slope (weights
    1/(2 dof) = 1/4) is 10 per s with SE sqrt(1 / sum w (t - 1.5)^2) = sqrt(1/1.25)."""
    def rec(r, chi2, rig="ecore"):
        return ResidualEntry(r, rig, 40.0, 1.27, float(r), "force_N", "force vs flux", "1", chi2, 2)
    trend = locate([rec(r, 2.0 + 10.0 * r) for r in range(4)]).to_json()["time"]
    assert trend[0]["label"] == "ecore" and (trend[0]["first_s"], trend[0]["last_s"]) == (0.0, 3.0)
    assert trend[0]["z"] == pytest.approx(10 / math.sqrt(1 / 1.25), abs=1e-3)
    # A large excess that does not move along the sweep: its scatter, not the null, sets the SE.
    flat = locate([rec(r, c) for r, c in enumerate((300.0, 340.0, 310.0, 330.0, 320.0, 300.0))]).to_json()["time"]
    assert abs(flat[0]["z"]) < 3


def test_empty_views_and_missing_start_times_give_nan_free_json():
    empty = locate([])
    assert empty.top() == [] and empty.grid()[0] == [] and empty.grid()[1] == []
    assert all(v == [] for v in empty.to_json().values())
    json.dumps(empty.to_json(), allow_nan=False)
    no_time = locate(_table(start=False)).to_json()
    assert no_time["time"][0]["note"] == "no start_time_s" and no_time["time"][0]["z"] is None
    json.dumps(no_time, allow_nan=False)
    json.dumps(locate(_table()).to_json(), allow_nan=False)
    one = locate([ResidualEntry(0, "ecore", 40.0, 1.27, 5.0, "flux_Wb", "flux vs current", "1", 3.0, 2)])
    json.dumps(one.to_json(), allow_nan=False)
    assert one.to_json()["channels"] == [{"label": "flux vs current", "z": chi2_z(3.0, 2), "chi2": 3.0, "dof": 2}]


def test_grid_rows_columns_and_cells():
    table = _table()
    rows, cols, z = locate(list(reversed(table))).grid()
    assert rows[0] == "flux vs current, k=0" and rows[-1] == "force_N alone, line 50 Hz"
    assert cols == ["ecore_pm 40 Hz 1.4 A", "ecore_pm 120 Hz 1.4 A", "ecore_pm 480 Hz 1.4 A"]  # by start time
    assert z.shape == (9, 3)
    assert z[rows.index("force vs flux, k=0"), 1] == pytest.approx((202 - 2) / 2)
    assert z[rows.index("force vs flux, k=0"), 0] == pytest.approx(0.0)


def test_a_non_finite_chi2_is_refused_naming_the_entry():
    bad = ResidualEntry(4, "ecore", 40.0, 1.27, None, "force_N", "force vs flux", "2", math.nan, 2)
    with pytest.raises(ValueError, match="record 4 .*force_N.*harmonic 2"):
        locate([bad])
