"""The compiled median and MAD (:mod:`hystbench.analysis.estimation._median_kernel`, issue 14)
against numpy's, in one process.

A median and a MAD are exact order statistics, so the kernel must give numpy's numbers bit for bit
(``np.median``, and an independent sort), whatever the data: ties, infinities, NaN, sorted and
adversarial orders, one sample.  The outlier screen built on it must flag the very same samples
(its shortcut: a row whose largest deviation is within k MADs has nothing to compare), and the
method's estimates on simulated-rig windows, with and without glitches, must be identical.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from hystbench.analysis.estimation import _median_kernel, _outliers
from hystbench.analysis.method import measure_window
from hystbench.jit import enabled

from .conftest import in_fresh_thread
from .test_lsq_kernel import FS, _windows

pytestmark = pytest.mark.skipif(not enabled(), reason="numba missing or HYSTBENCH_JIT=0: no kernel to compare")


def _numpy(x: np.ndarray) -> tuple[float, float, float]:
    """The reference: numpy's median, the median of the absolute deviations, their largest."""
    med = np.median(x)
    dev = np.abs(x - med)
    return float(med), float(np.median(dev)), float(dev.max())


def _sorted_median(v: np.ndarray) -> float:
    s = np.sort(v)
    m = s.size // 2
    return float(s[m]) if s.size % 2 else (float(s[m - 1]) + float(s[m])) / 2.0


def _same(got: tuple[float, float, float], want: tuple[float, float, float]) -> None:
    """Equal bit for bit (NaN where numpy gives NaN)."""
    for g, w in zip(got, want):
        assert (np.isnan(g) and np.isnan(w)) or g == w, (got, want)


@settings(max_examples=300, deadline=None)
@given(st.lists(st.floats(allow_nan=False, allow_infinity=False, min_value=-1e300, max_value=1e300), min_size=1,
                max_size=2000))
def test_any_finite_row_gives_numpys_median_mad_and_largest_deviation(values):
    x = np.array(values, dtype=np.float64)
    with np.errstate(over="ignore", invalid="ignore"):
        want = _numpy(x)
    got = _median_kernel.median_mad(x)
    _same(got, want)
    assert np.array_equal(x, np.array(values)), "the kernel changed its input"
    if np.isfinite(want[1]):
        assert got[0] == _sorted_median(x) and got[1] == _sorted_median(np.abs(x - got[0]))


@settings(max_examples=200, deadline=None)
@given(st.integers(1, 5000), st.integers(1, 40), st.integers(0, 2**32 - 1))
def test_rows_full_of_ties_give_numpys_numbers(n, levels, seed):
    x = np.random.default_rng(seed).integers(0, levels, n).astype(np.float64)  # a quantised channel
    _same(_median_kernel.median_mad(x), _numpy(x))


@pytest.mark.parametrize("n", [1, 2, 3, 600, 601, 602, 5_000, 25_001, 100_000])
@pytest.mark.parametrize("order", ["sorted", "reversed", "organ pipe", "constant", "sine", "sawtooth"])
def test_ordered_rows_give_numpys_numbers(n, order):
    i = np.arange(n, dtype=np.float64)
    x = {"sorted": i, "reversed": i[::-1].copy(), "organ pipe": np.minimum(i, n - 1 - i), "constant": np.full(n, 3.5),
         "sine": np.sin(2 * np.pi * i / 2500.0), "sawtooth": i % 97}[order]
    _same(_median_kernel.median_mad(x), _numpy(x))


@pytest.mark.parametrize("x", [
    [np.nan], [1.0, np.nan, 3.0], [np.inf], [-np.inf, np.inf], [1.0, np.inf], [np.inf, np.inf, 1.0],
    [-np.inf, 0.0, 1.0, 2.0, np.inf], [1e308, -1e308, 1e308], [0.0, -0.0, 0.0, -0.0], [5e-324, -5e-324, 0.0]])
def test_infinities_and_nan_give_what_numpy_gives(x):
    x = np.array(x, dtype=np.float64)
    with np.errstate(over="ignore", invalid="ignore"):
        want = _numpy(x)
    _same(_median_kernel.median_mad(x), want)


def test_an_adversarial_order_is_still_exact_past_the_round_limit(monkeypatch):
    x = np.random.default_rng(5).permutation(np.repeat(np.arange(400.0), 7))
    want = _numpy(x)
    # a tiny limit: the selection sorts what is left almost at once (numba reads the module's
    # constant when compiling, so the plain-Python kernel is what is run here)
    monkeypatch.setattr(_median_kernel, "MAX_ROUNDS", 1)
    select = _median_kernel._select.py_func
    monkeypatch.setattr(_median_kernel, "_select", select)
    a = x.copy()
    got = select(a, a.size // 2)
    assert got == np.sort(x)[x.size // 2]
    assert np.all(a[: a.size // 2] <= got) and np.all(a[a.size // 2:] >= got)
    _same(_median_kernel.median_mad(x), want)


def _masks(compiled: bool, data: np.ndarray, exclude: np.ndarray | None) -> tuple:
    """The screen's first-fit mask and its flags after one fit, numpy's or the kernel's path."""
    def run():
        _outliers.KERNEL = compiled
        try:
            first = _outliers.initial_mask(data, exclude, 9.0)
            sol, mask = _outliers.robust_solve(data, FS, np.full(data.shape[0], 160.0), (1, 2, 3, 4), fit_freq=True,
                                               max_iter=50, tol=1e-10, exclude=exclude, mask=first, sigmas=9.0,
                                               names=tuple(f"x{c}" for c in range(data.shape[1])))
            return first, mask, sol.freq, sol.coef
        finally:
            _outliers.KERNEL = True
    return in_fresh_thread(run)


@pytest.mark.parametrize("glitches", ["none", "spikes", "huge", "excluded"])
def test_outlier_screen_flags_the_same_samples(glitches):
    _, (w,) = _windows("ecore_pm", (160.0,))
    data = np.stack([w["current_A"], w["flux_Wb"], w["force_N"]])[None].copy()  # (1, 3, N)
    exclude = None
    if glitches == "spikes":
        data[0, 0, [17, 4000]] += 30 * data[0, 0].std()
        data[0, 2, 555] -= 12 * data[0, 2].std()
    elif glitches == "huge":
        data[0, 1, 1234] = 1e300
    elif glitches == "excluded":
        exclude = np.zeros(data.shape, dtype=bool)
        exclude[0, 1, 100:140] = True
        data[0, 2, 3000] += 30 * data[0, 2].std()
    ref, got = _masks(False, data, exclude), _masks(True, data, exclude)
    for r, g in zip(ref, got):
        assert (r is None and g is None) or np.array_equal(r, g)
    if glitches != "none":
        assert ref[1] is not None and ref[1].any()


@pytest.mark.parametrize("rig, frequencies, spikes", [("ecore_pm", (40.0, 480.0), False), ("ecore_pm", (160.0,), True),
                                                      ("ecore", (120.0,), True)])
def test_method_estimates_identical_to_numpys_screen(rig, frequencies, spikes):
    magnet, windows = _windows(rig, frequencies)
    for f, chans in zip(frequencies, windows):
        if spikes:
            chans = {c: x.copy() for c, x in chans.items()}
            for c, x in chans.items():
                x[[101, 2002, 3003]] += 50.0 * np.std(x)
        res = {}
        for compiled in (True, False):
            def run(compiled=compiled, chans=chans, f=f):
                _outliers.KERNEL = compiled
                try:
                    return measure_window(chans, FS, f, magnet=magnet)
                finally:
                    _outliers.KERNEL = True
            res[compiled] = in_fresh_thread(run)
        got, ref = res[True], res[False]
        if spikes:
            assert any(ref.outliers.values())
        assert got.outliers == ref.outliers
        assert got.frequency_hz == ref.frequency_hz and got.frequency_std_hz == ref.frequency_std_hz
        assert got.delays_s == ref.delays_s and got.delays_std_s == ref.delays_std_s
        assert got.explained == ref.explained
