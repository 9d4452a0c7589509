"""The histogram bound that spares the outlier screen most medians (:func:`_median_kernel.within_mads`,
issue 14).

The screen asks of each row whether any sample lies more than k MADs from the median; a row the
bound settles is not given its median and MAD at all.  So the bound must never say "within" of a
row that has a sample beyond: checked here against numpy's median and MAD (the reference, taken
independently) on many rows, with k just below and just above each row's own ratio of largest
deviation to MAD, where a loose proof would show.  It must also settle the rows it is for (a sine,
Gaussian residuals: their ratios, sqrt(2) and ~5.5, are far below the screen's 100 and 13.3), and
refuse what it cannot judge (NaN, infinities, flat or nearly flat rows, a few samples).
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from hystbench.analysis.estimation import _median_kernel, _outliers
from hystbench.jit import enabled

pytestmark = pytest.mark.skipif(not enabled(), reason="numba missing or HYSTBENCH_JIT=0: no kernel to check")


def _ratio(x: np.ndarray) -> float:
    """numpy's largest absolute deviation from the median over the MAD (inf for a zero MAD)."""
    med = np.median(x)
    dev = np.abs(x - med)
    mad = np.median(dev)
    return float(dev.max() / mad) if mad > 0 else np.inf


def _rows(seed: int) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)
    n = int(rng.integers(3, 30_000))
    t = np.arange(n)
    return [
        rng.standard_normal(n),
        np.sin(2 * np.pi * rng.uniform(1e-4, 0.3) * t) + 1e-3 * rng.standard_normal(n),
        rng.standard_t(2, n),  # heavy tails: ratios of tens to thousands
        rng.uniform(-1, 1, n) ** 9,  # piled up at 0
        np.round(rng.standard_normal(n) * rng.uniform(1, 20)),  # quantised
        1e9 + 1e-3 * rng.standard_normal(n),  # a large offset: roundings of whole bins' size
        np.where(rng.random(n) < 0.002, 40.0, 1.0) * rng.standard_normal(n),  # a few spikes
    ]


@pytest.mark.parametrize("seed", range(40))
def test_within_never_said_of_a_row_with_a_sample_beyond(seed):
    for x in _rows(seed):
        r = _ratio(x)
        for k in (1.0, 2.0, 5.0, 13.343419966550417, 100.0, r * (1 - 1e-12), r * 0.999, r * 1.5, r * 3.0):
            if _median_kernel.within_mads(x, float(k)):
                assert r <= k, f"n={x.size}: said within {k} MADs, the largest deviation is {r} MADs"


@settings(max_examples=300, deadline=None)
@given(st.lists(st.floats(-1e6, 1e6, allow_nan=False), min_size=1, max_size=400), st.floats(0.5, 200.0))
def test_within_holds_for_any_row(values, k):
    x = np.array(values, dtype=np.float64)
    if _median_kernel.within_mads(x, k):
        assert _ratio(x) <= k


def test_a_row_spanning_subnormals_is_not_settled():
    """A span so small that bins per unit overflow (found by hypothesis): MAD 0, the largest deviation
    beyond any k; the bound must say 'unknown'."""
    assert not _median_kernel.within_mads(np.array([0.0, 0.0, 2.225073858507203e-309]), 1.0)


def test_clean_rows_are_settled():
    rng = np.random.default_rng(7)
    n = 3125
    sine = 0.7 * np.sin(2 * np.pi * 40.0 * np.arange(n) / 100_000.0 + 0.3) + 0.1  # ratio sqrt(2)
    noise = 1e-3 * rng.standard_normal(25_000)  # ratio ~ 4.4 sigma / 0.674 sigma
    assert _median_kernel.within_mads(sine, _outliers.GROSS_MADS)
    assert _median_kernel.within_mads(noise, 9.0 * 1.482602218505602)
    assert not _median_kernel.within_mads(noise, 3.0)  # its largest deviation is more than 3 MADs


@pytest.mark.parametrize("x", [np.array([1.0, np.nan, 2.0, 3.0]), np.array([0.0, np.inf, 1.0, 2.0]),
                               np.array([-1e308, 1e308, 0.0, 1.0]), np.full(100, 2.5), np.array([1.0, 2.0])])
def test_what_it_cannot_judge_is_left_to_the_median(x):
    assert not _median_kernel.within_mads(x, 1e9)
