"""Force vs flux in the located mismatch (analysis/diagnosis/locate.py: locate_residual): each side's
force referenced to its own flux, so a mismatch of the iron (flux and force lagging the current
together) leaves it clean while force vs current shows it; a force instrument's lag shows in both."""

from __future__ import annotations

import numpy as np

from hystbench.analysis.diagnosis.features import RecordFeatures
from hystbench.analysis.diagnosis.locate import locate_residual
from hystbench.analysis.diagnosis.vector import layout_of, values_of

K = 4


def _features(flux_lag: float, force_lag: float) -> RecordFeatures:
    k = np.arange(K + 1)
    flux = np.array([np.nan, 1e-4, 2e-6, 1e-6, 5e-7]) * np.exp(-1j * k * flux_lag)
    force = np.array([5.0, 2.0, 0.4, 0.05, 0.01]) * np.exp(-1j * k * (flux_lag + force_lag))
    current = np.array([0.0, 0.7, 0, 0, 0], complex)
    se = {"current_A": np.full(K + 1, 1e-6), "flux_Wb": np.full(K + 1, 1e-9), "force_N": np.full(K + 1, 1e-4)}
    return RecordFeatures("r", "ecore_pm", 80.0, 1.4, 0.0, 0.6, 1e5, 48,
                          {"current_A": current, "flux_Wb": flux, "force_N": force}, se, {}, {}, {})


def _views(data_lags, model_lags) -> dict[str, float]:
    data, model = [_features(*data_lags)], [_features(*model_lags)]
    layout = layout_of(data)
    d, m = values_of(data, layout), values_of(model, layout)
    sigma = layout.se.copy()
    located, _ = locate_residual(data, layout, d - m, sigma, np.isfinite(d - m), [], np.zeros(0), np.zeros(0), m)
    return {c["label"]: c["chi2"] for c in located["channels"]}


def test_an_iron_lag_shows_against_current_not_in_force_vs_flux():
    chi2 = _views((0.010, 0.0), (0.0, 0.0))  # the data's flux (and so force) lag 10 mrad more
    assert chi2["force vs flux"] < 1e-6
    assert chi2["force vs current"] > 1e3 and chi2["flux vs current"] > 1e3


def test_a_force_instrument_lag_shows_in_force_vs_flux():
    chi2 = _views((0.0, 0.005), (0.0, 0.0))  # only the force lags: the load cell, not the iron
    assert chi2["force vs flux"] > 1e3
    assert chi2["flux vs current"] < 1e-6
