"""The fits in bounded memory (issue 10) give the dense implementation's results to rounding.

The oracle is the estimators as they were before the sums went block by block, frozen in
``dense_estimation_reference/`` (every N x K design matrix built at once; validated against the
Cramer-Rao bound).  On fixed seeds both run on the same records: long ones (many blocks, the start
frequency from the grid scan), batches of short ones, glitches found and refitted, caller
exclusions, noiseless data.  Delays must agree to 1e-9 relative or a hundred-thousandth of their
standard error (the frequency search stops on steps of 1e-6 of its standard error, so rounding may
end it one step apart), outlier masks exactly; the start-frequency scan (a chirp-z transform per
block now, direct sums per grid point before) picks the same grid point.  Then the memory: a fit's
traced peak is a few arrays of the record's size, not N x (parameters).
"""

from __future__ import annotations

import importlib
import importlib.util
import sys
import tracemalloc
from pathlib import Path

import numpy as np
import pytest

from hystbench.acquisition import estimation
from hystbench.acquisition.estimation import _lsq

HARMONICS = (1, 2, 3, 4)  # what the method fits
FS = 100_000.0


def _reference():
    """The frozen dense estimators, imported as their own package."""
    name = "dense_estimation_reference"
    if name not in sys.modules:
        folder = Path(__file__).with_name(name)
        spec = importlib.util.spec_from_file_location(name, folder / "__init__.py",
                                                      submodule_search_locations=[str(folder)])
        module = importlib.util.module_from_spec(spec)
        sys.modules[name] = module
        spec.loader.exec_module(module)
    return (importlib.import_module(f"{name}.sinefit"), importlib.import_module(f"{name}.covariance"))


DENSE, DENSE_COV = _reference()


def _channels(n: int, seed: int, *, batch: tuple[int, ...] = (), f: float = 320.013, snr_db: float = 50.0):
    """Current-like and force-like channels: a sine with a few harmonics, DC, white noise."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) / FS
    phi = rng.uniform(-np.pi, np.pi, batch + (1,))
    w = 2 * np.pi * f * t
    x = 0.7 * np.cos(w + phi) + 0.02 * np.cos(2 * w + phi + 0.3) + 0.1
    y = 45.0 * np.cos(w + phi - 0.07) + 3.0 * np.cos(2 * w + 2 * phi + 1.1) + 0.5 * np.cos(3 * w - 0.4) + 175.0
    for arr, amp in ((x, 0.7), (y, 45.0)):
        arr += rng.normal(0.0, amp / np.sqrt(2 * 10 ** (snr_db / 10)), arr.shape)
    return x, y


def _assert_same_delay(new, ref) -> None:
    d_new, d_ref, se = np.asarray(new.delay_s), np.asarray(ref.delay_s), np.asarray(ref.delay_se_s)
    gap = np.abs(d_new - d_ref)
    assert np.all(gap <= np.maximum(1e-9 * np.abs(d_ref), 1e-5 * se)), np.max(gap / se)
    f_gap = np.abs(np.asarray(new.freq_hz) - ref.freq_hz)
    assert np.all(f_gap <= np.maximum(1e-12 * ref.freq_hz, 1e-5 * ref.freq_se_hz)), np.max(f_gap / ref.freq_se_hz)
    # standard errors: evaluated at those frequencies (an error is itself known to ~1/sqrt(2N) only)
    np.testing.assert_allclose(new.delay_se_s, ref.delay_se_s, rtol=1e-4)
    np.testing.assert_allclose(new.freq_se_hz, ref.freq_se_hz, rtol=1e-4)
    for a, b in ((new.x, ref.x), (new.y, ref.y)):
        np.testing.assert_array_equal(a.excluded, b.excluded)
        # rounding: relative to the value, or to the record's scale (noiseless data: se ~ eps)
        scale = np.max(b.amplitude, axis=-1) + np.abs(b.offset)
        for name, se_name, floor in (("amplitude", "amplitude_se", scale[..., None]),
                                     ("phase_rad", "phase_se_rad", 1.0), ("offset", "offset_se", scale)):
            want, se = getattr(b, name), getattr(b, se_name)
            gap = np.abs(getattr(a, name) - want)
            close = gap <= np.maximum(1e-9 * np.maximum(np.abs(want), 1e-3 * floor), 1e-5 * se)
            if name == "phase_rad":
                close |= se > 0.1  # an absent harmonic (noiseless data) has no phase to compare
            assert np.all(close), name
        np.testing.assert_allclose(a.noise_std, b.noise_std, rtol=1e-6, atol=1e-12 * np.max(scale))
        assert np.all(a.converged == b.converged)


@pytest.mark.parametrize("seed", [0, 1])
def test_a_long_record_with_glitches_gives_the_dense_delays_and_outliers(seed: int) -> None:
    # 300 000 samples: five blocks, and a search window wider than half a bin (the grid scan runs)
    x, y = _channels(300_000, seed)
    y[[7, 123_456, 299_999]] = (1e308, 2000.0, -300.0)  # gross, large, and one hidden by the others
    x[65_536] += 0.3
    kw = dict(harmonic=1, harmonics=HARMONICS)
    new, ref = estimation.phase_delay(x, y, FS, 320.0, **kw), DENSE.phase_delay(x, y, FS, 320.0, **kw)
    assert new.y.outliers.tolist() == [7, 123_456, 299_999] and new.x.outliers.tolist() == [65_536]
    _assert_same_delay(new, ref)


def test_the_method_s_second_fits_with_exclusions_and_a_given_frequency() -> None:
    x, y = _channels(200_000, 2)
    drive = (x - x.mean()) ** 2  # the no-magnet reference: its 2f component
    ex_x, ex_y = np.zeros(x.size, bool), np.zeros(x.size, bool)
    ex_x[[10, 90_000]], ex_y[[5, 150_001, 150_002]] = True, True
    kw = dict(harmonic=2, harmonics=HARMONICS, exclude=(ex_x, ex_y), outlier_sigmas=None)
    _assert_same_delay(estimation.phase_delay(drive, y, FS, 320.013, **kw), DENSE.phase_delay(drive, y, FS, 320.013, **kw))
    new = estimation.sine_fit(y, FS, 320.013, harmonics=HARMONICS, fit_freq=False, exclude=ex_y)
    ref = DENSE.sine_fit(y, FS, 320.013, harmonics=HARMONICS, fit_freq=False, exclude=ex_y)
    np.testing.assert_allclose(new.phase_rad, ref.phase_rad, rtol=0, atol=1e-12)
    np.testing.assert_allclose(new.phase_se_rad, ref.phase_se_rad, rtol=1e-9)
    np.testing.assert_array_equal(new.excluded, ref.excluded)


@pytest.mark.parametrize(("batch", "n"), [((40,), 5_000), ((3, 700), 63)])
def test_batches_of_records_give_the_dense_delays(batch, n: int) -> None:
    x, y = _channels(n, 3, batch=batch, snr_db=30.0)
    x.reshape(-1, n)[::7, n // 3] += 50.0  # a glitch in every seventh record
    kw = dict(harmonics=(1, 2))
    _assert_same_delay(estimation.phase_delay(x, y, 10_000.0, 320.0, **kw), DENSE.phase_delay(x, y, 10_000.0, 320.0, **kw))


def test_noiseless_records_and_find_outliers_across_three_channels() -> None:
    t = np.arange(150_000) / FS
    chans = [np.cos(2 * np.pi * 320.0071 * t + p) * a + dc for p, a, dc in ((0.1, 1.0, 0.0), (0.5, 0.02, 1.0),
                                                                              (-0.3, 40.0, 175.0))]
    kw = dict(harmonic=1, harmonics=HARMONICS)
    _assert_same_delay(estimation.phase_delay(chans[0], chans[1], FS, 320.0, **kw),
                       DENSE.phase_delay(chans[0], chans[1], FS, 320.0, **kw))
    chans[2] = chans[2] + np.random.default_rng(4).normal(0.0, 0.05, t.size)
    chans[2][[3, 77_777]] = (1e6, 176.0 + 40.0)
    new, f_new = estimation.find_outliers(chans, FS, 320.0, harmonics=HARMONICS)
    ref, f_ref = DENSE.find_outliers(chans, FS, 320.0, harmonics=HARMONICS)
    assert [m.nonzero()[0].tolist() for m in new] == [m.nonzero()[0].tolist() for m in ref] == [[], [], [3, 77_777]]
    assert f_new == pytest.approx(f_ref, rel=1e-12)


@pytest.mark.parametrize(("shape", "f"), [((400_000,), 320.0), ((25, 3_000), 640.0)])
def test_covariance_delay_gives_the_dense_lag(shape, f: float) -> None:
    n = shape[-1]
    x, y = _channels(n, 5, batch=shape[:-1], f=f)
    new, ref = estimation.covariance_delay(x, y, FS, f), DENSE_COV.covariance_delay(x, y, FS, f)
    np.testing.assert_array_equal(new.lag_samples, ref.lag_samples)
    np.testing.assert_array_equal(new.lags, ref.lags)
    np.testing.assert_allclose(new.covariance, ref.covariance, rtol=1e-9)


@pytest.mark.parametrize(("n", "batch", "ks", "snr_db"), [(1_000_000, (), (1, 2, 3, 4), 50.0), (400_000, (), (2,), 0.0),
                                                       (200_000, (3,), (1, 2, 3, 4), 20.0)])
def test_the_start_frequency_scan_picks_the_dense_grid_point(n: int, batch, ks, snr_db: float) -> None:
    # the grid over +-200 ppm has ~N points; the chirp-z transform must rank them as the direct sums do
    x, y = _channels(n, 7, batch=batch, snr_db=snr_db)
    data = np.stack([x.reshape(-1, n), y.reshape(-1, n)], axis=1)
    mask = np.zeros(data.shape, bool)
    mask[:, 1, ::5000] = True  # left out: counted as the channel's median
    fill = np.median(data, axis=-1)
    dense = importlib.import_module("dense_estimation_reference._lsq")
    clean = np.where(mask, fill[..., None], data)
    for args in ((data, None, None), (data, mask, fill)):
        want = dense.grid_start(data if args[1] is None else clean, FS, 320.0, ks, 0.064)
        got = _lsq.grid_start(args[0], FS, 320.0, ks, 0.064, args[1], args[2])
        assert np.array_equal(got, want), (got - want) / (FS / (n * ks[-1]) / 4)  # in grid steps


def _traced_peak(fn) -> int:
    tracemalloc.start()
    try:
        tracemalloc.reset_peak()
        fn()
        return tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


def test_a_fit_needs_a_few_record_sized_arrays_not_n_by_parameters() -> None:
    # 2^19 samples: one float64 channel is 4 MiB; the dense fit of 4 harmonics peaked at 37 of them
    n = 1 << 19
    x, y = _channels(n, 6)
    y[1000] = 1e6
    channel = 8 * n
    peak = _traced_peak(lambda: estimation.phase_delay(x, y, FS, 320.0, harmonic=1, harmonics=HARMONICS))
    assert peak < 8 * channel, peak / channel  # the stacked pair, a residual, a median's copy, masks
    peak = _traced_peak(lambda: estimation.covariance_delay(x, y, FS, 320.0))
    assert peak < 2 * channel, peak / channel  # was 9: the whole record's FFTs; now blocks of 2^16
