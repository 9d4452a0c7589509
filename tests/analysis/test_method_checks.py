"""check_channels (issue 14: one min and max a channel instead of separate finite, flat and range
passes) refuses the same input, with the same words, and judges clipping by the same shares."""

import math

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from hystbench.analysis import method
from hystbench.analysis.method import measure_window
from hystbench.errors import EstimationError

FS, F = 100_000.0, 320.0


def _window(n: int = 3125) -> dict[str, np.ndarray]:
    t = np.arange(n) / FS
    w = 2 * np.pi * F * t
    return {"current_A": 2.0 * np.sin(w), "flux_Wb": 1e-3 * np.sin(w - 0.1), "force_N": 100 + 40 * np.sin(w - 0.2)}


def _refused(chans, *words) -> str:
    with pytest.raises(EstimationError) as err:
        measure_window(chans, FS, F, magnet=True, where="win_7")
    msg = str(err.value)
    assert msg.startswith("win_7: "), msg
    for w in words:
        assert w in msg, msg
    return msg


@pytest.mark.parametrize("bad", [np.inf, -np.inf, np.nan])
def test_a_nonfinite_sample_is_named_with_the_first_index(bad):
    chans = _window()
    chans["flux_Wb"][[40, 900]] = bad, np.nan
    _refused(chans, "'flux_Wb'", "2 NaN or infinite", "sample 40")


def test_a_channel_flat_but_for_one_gross_outlier():
    chans = _window()
    chans["force_N"] = np.full(3125, 7.0)
    chans["force_N"][1000] = 1e308
    _refused(chans, "'force_N'", "flat apart from 1 outlier", "first at 1000")


def test_a_flat_channel():
    chans = _window()
    chans["current_A"] = np.full(3125, -0.5)
    _refused(chans, "'current_A'", "flat (every sample -0.5)")


def test_an_empty_window_is_refused_by_name():
    _refused({c: np.zeros(0) for c in ("current_A", "flux_Wb", "force_N")}, "'current_A'", "no samples")


def test_a_clipped_channel_is_judged_without_its_gross_outlier():
    chans = _window()
    f = chans["force_N"]
    chans["force_N"] = np.minimum(f, 130.0)  # 40 N sine about 100 N cut at 130 N: a quarter of it pinned
    chans["force_N"][5] = 1e308  # would make the max, and every other sample sit below it
    _refused(chans, "'force_N'", "looks clipped", "sit at 130")


@pytest.mark.parametrize("per_period, phase", [(20, 0.0), (20, math.pi / 20), (10, 0.3), (16, 0.0)])
def test_a_sine_sampled_in_step_with_its_period_is_not_clipped(per_period, phase):
    """A clock locked to the generator: every period meets the extreme at the same one sample (or two
    straddling the peak), 5-10 % of the record at its minimum; it was refused as clipped.  Cut at 90 %
    of its swing, the same record is."""
    n = 40 * per_period
    w = 2 * np.pi * np.arange(n) / per_period + phase
    chans = {"current_A": 2.0 * np.sin(w), "flux_Wb": 1e-3 * np.sin(w - 0.1), "force_N": 100 + 40 * np.sin(w - 0.2)}
    fs = F * per_period
    assert np.count_nonzero(chans["flux_Wb"] <= chans["flux_Wb"].min() + 1e-15) / n >= 1 / per_period
    d = measure_window(chans, fs, F, magnet=True, where="win_7")
    assert d.frequency_hz == pytest.approx(F, rel=1e-6)  # measured, not refused
    f = chans["force_N"]
    chans["force_N"] = np.minimum(f, f.min() + 0.9 * np.ptp(f))
    with pytest.raises(EstimationError, match="'force_N' looks clipped"):
        measure_window(chans, fs, F, magnet=True, where="win_7")


@settings(max_examples=200, deadline=None)
@given(st.lists(st.integers(-5, 5), min_size=1, max_size=400), st.floats(1e-6, 1e6))
def test_pinned_share_is_the_mean_of_the_samples_at_an_extreme(codes, step):
    x = np.array(codes, dtype=np.float64) * step
    lo, hi = float(x.min()), float(x.max())
    tol = 1e-12 * max(abs(lo), abs(hi), hi - lo)
    at_hi, at_lo = float(np.mean(x >= hi - tol)), float(np.mean(x <= lo + tol))  # the old computation
    want = (at_hi, hi) if at_hi >= at_lo else (at_lo, lo)
    assert method._pinned_fraction(x, lo, hi) == want
    assert math.isclose(want[0], max(np.sum(x == hi), np.sum(x == lo)) / x.size)
