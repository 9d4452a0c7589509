"""The explicit discrepancy (analysis/diagnosis/discrepancy.py): the iron's misfit reaches the force only
through the force law, and each path's columns act where the bench's structure says they may."""

from __future__ import annotations

import numpy as np

from hystbench.analysis.diagnosis.discrepancy import _force_law_slope, discrepancy_columns
from hystbench.analysis.diagnosis.vector import CHANNELS, Layout

K = 5


def _layout(n_records: int) -> Layout:
    rows = [(r, ci, k, p) for r in range(n_records) for ci in range(len(CHANNELS)) for k in range(K + 1)
            for p in (0, 1) if not (p == 1 and k == 0) and not (CHANNELS[ci] == "flux_Wb" and k == 0)]
    rec, chan, harm, part = (np.array(x) for x in zip(*rows))
    return Layout(rec, chan, harm, part, np.full(rec.size, 1e-6), np.ones(rec.size))


def _vector(layout: Layout, harmonics: dict[str, np.ndarray]) -> np.ndarray:
    v = np.zeros(layout.size)
    for i in range(layout.size):
        h = harmonics.get(CHANNELS[layout.channel[i]])
        if h is not None:
            v[i] = h[layout.harmonic[i]].real if layout.part[i] == 0 else h[layout.harmonic[i]].imag
    return v


def _harmonics(x: np.ndarray) -> np.ndarray:
    """X_0 + sum Re(X_k e^{ikt}) of one densely sampled period."""
    spec = np.fft.rfft(x) / x.size
    return np.r_[spec[0].real, 2 * spec[1:K + 1]]


def test_an_iron_change_reaches_the_force_as_the_force_law_carries_it():
    # a magnet's bias and a quadratic law: F = a + b phi + c phi^2 (phi the flux's AC part)
    a, b, c = 170.0, 2.4e6, 3.0e9
    theta = 2 * np.pi * np.arange(4096) / 4096
    phi = 2e-5 * np.cos(theta) + 1e-6 * np.cos(3 * theta - 0.4)
    law = lambda p: a + b * p + c * p * p  # noqa: E731
    layout = _layout(1)
    m = _vector(layout, {"flux_Wb": _harmonics(phi), "force_N": _harmonics(law(phi))})
    carried = _force_law_slope(m, layout, 0, K)
    for k, dphi in ((1, 1e-7 + 2e-7j), (3, -3e-8j), (2, 5e-8)):
        step = np.real(dphi * np.exp(1j * k * theta))
        expected = _harmonics(law(phi + 1e-3 * step) - law(phi)) / 1e-3  # the law's own derivative, numerically
        got = carried(k, dphi)
        assert np.allclose(got, expected, atol=1e-6 * np.max(np.abs(expected))), (k, got, expected)


def test_paths_act_only_on_their_rows():
    layout = _layout(4)
    rng = np.random.default_rng(1)
    m = rng.normal(size=layout.size)

    class F:  # the features the columns read: rig, amplitude, frequency, channels present
        def __init__(self, f_hz, ipp):
            self.rig, self.current_pp_a, self.frequency_hz = "ecore_pm", ipp, f_hz
            self.harmonics = {"flux_Wb": None}

    data = [F(40.0, 0.7), F(320.0, 0.7), F(40.0, 1.4), F(320.0, 1.4)]
    cols = discrepancy_columns(data, {"ecore_pm": {"static_hysteresis": {}}}, layout, m)
    flux, force, command = (CHANNELS.index(c) for c in ("flux_Wb", "force_N", "command_V"))
    for col in cols:
        moved = np.flatnonzero(col.values)
        channels = set(layout.channel[moved])
        if ".iron." in col.name:  # the flux, and the force through the law: never the current or command
            assert channels <= {flux, force} and flux in channels, col.name
            group = {0, 1} if "@0.7A" in col.name else {2, 3}
            assert set(layout.record[moved]) <= group, col.name  # one rig and amplitude
        elif ".law." in col.name:  # the force alone, the same at every frequency of its group
            assert channels == {force}, col.name
            assert len(set(np.round(col.values[moved], 12))) == 1, col.name
        else:  # the amplifier: the command's fundamental, a share of it
            assert ".amplifier." in col.name and channels == {command}, col.name
            assert set(layout.harmonic[moved]) == {1}, col.name
