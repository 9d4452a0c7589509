"""The raw rows' median and MAD remembered per thread (issue 14) are the numbers computed afresh.

The live estimator's window goes through the clipping check (gross outliers of each channel) and
then its fits, which take the same gross outliers out first: the same medians twice.  They are
now remembered by each row's bytes; a median and a MAD are exact order statistics, so the
reference is :func:`_outliers._mad` on the same rows, and an independent sort-based median.
"""

from __future__ import annotations

import numpy as np

from hystbench.analysis.estimation import _outliers, gross_outliers

from .conftest import in_fresh_thread


def _sorted_median(v: np.ndarray) -> float:
    s = np.sort(v)
    m = s.size // 2
    return float(s[m]) if s.size % 2 else 0.5 * (float(s[m - 1]) + float(s[m]))


def test_remembered_rows_give_the_medians_computed_afresh():
    rng = np.random.default_rng(7)
    rows = [rng.normal(size=n) for n in (2_000, 2_000, 2_001)]
    rows[1][::3] = rows[1][1::3][: rows[1][::3].size]  # ties
    pair = np.stack(rows[:2])

    def run():
        first = _outliers._raw_mad(pair)  # both rows made, remembered
        hit = _outliers._raw_mad(pair[1:])  # one of them, alone: remembered
        again = _outliers._raw_mad(pair)
        odd = _outliers._raw_mad(rows[2][None])
        for i in range(_outliers.RECENT_ROWS + 2):  # push them out
            _outliers._raw_mad(rng.normal(size=(1, 50)))
        evicted = len(_outliers._recent.rows) <= _outliers.RECENT_ROWS
        return first, hit, again, odd, evicted

    first, hit, again, odd, evicted = in_fresh_thread(run)
    assert evicted
    for i, row in enumerate(rows):
        med = _sorted_median(row)
        mad = _sorted_median(np.abs(row - med))
        got = [odd] if i == 2 else ([first, again] + ([hit] if i == 1 else []))
        for m, d, top in got:  # top: the largest deviation (+inf when numpy took the median: unknown)
            j = 0 if i == 2 else (i if m.shape[0] == 2 else 0)
            assert m[j, 0] == med and d[j, 0] == mad
            assert top[j, 0] in (np.max(np.abs(row - med)), np.inf)


def test_gross_outliers_the_same_in_a_fresh_and_a_busy_thread():
    rng = np.random.default_rng(3)
    x = np.sin(np.linspace(0, 60, 25_000)) + rng.normal(0, 1e-3, 25_000)
    x[[10, 20_000]] = 1e308, -400.0  # 100 MADs of a unit sine: ~70
    cold = in_fresh_thread(lambda: gross_outliers(x))

    def busy():
        gross_outliers(x)
        _outliers.initial_mask(np.stack([x, -x])[None], None, 9.0)
        return gross_outliers(x)

    warm = in_fresh_thread(busy)
    assert np.flatnonzero(cold).tolist() == [10, 20_000]
    assert np.array_equal(cold, warm)


def test_rows_alike_at_the_sampled_points_are_told_apart():
    """A row is looked up by a few of its samples, then compared whole: a row equal to a remembered
    one at those samples but not elsewhere gets its own median."""
    rng = np.random.default_rng(11)
    a = rng.normal(size=3_000)
    b = a.copy()
    sampled = np.zeros(a.size, dtype=bool)
    sampled[:: a.size // 64] = True
    b[~sampled] += 10.0  # the same key, another median
    assert _outliers._row_key(a) == _outliers._row_key(b)

    def run():
        return _outliers._raw_mad(a[None]), _outliers._raw_mad(b[None]), _outliers._raw_mad(a[None])

    got_a, got_b, again_a = in_fresh_thread(run)
    for row, (m, d, _) in ((a, got_a), (b, got_b), (a, again_a)):
        med = _sorted_median(row)
        assert m[0, 0] == med and d[0, 0] == _sorted_median(np.abs(row - med))
