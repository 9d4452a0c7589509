"""The fits in bounded memory (issue 10) give the dense computation's results to rounding.

The oracle, ``dense_oracle``, is a small independent dense computation: per record the whole
N x p design matrix solved by ``np.linalg.lstsq``, the frequency as the root of the likelihood's
derivative (``scipy.optimize.brentq``), the covariance from the whole information matrix, the
outlier rule on whole residual arrays, the start grid by direct Fourier sums, Eq. 3 by
``np.correlate``.  On fixed seeds both run on the same records: long ones (many blocks, the start
frequency from the grid scan), batches of short ones, glitches found and refitted, caller
exclusions, noiseless data.  Delays must agree to 1e-9 relative or a hundred-thousandth of their
standard error (the frequency search stops on steps of 1e-6 of its standard error), outlier masks
exactly; the start-frequency scan (a chirp-z transform per block) picks the grid point the direct
sums pick.  Then the memory: a fit's traced peak is a few arrays of the record's size, not
N x (parameters).
"""

from __future__ import annotations

import tracemalloc

import numpy as np
import pytest

from hystbench.analysis import estimation
from hystbench.analysis.estimation import _lsq

from . import dense_oracle as dense

pytestmark = pytest.mark.slow(12)  # ~12 s: handed to a worker before lighter files (tests/conftest.py)

HARMONICS = (1, 2, 3, 4)  # what the method fits
FS = 100_000.0


def _channels(n: int, seed: int, *, batch: tuple[int, ...] = (), f: float = 320.013, snr_db: float = 50.0,
              fs: float = FS):
    """Current-like and force-like channels: a sine with a few harmonics, DC, white noise."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) / fs
    phi = rng.uniform(-np.pi, np.pi, batch + (1,))
    w = 2 * np.pi * f * t
    x = 0.7 * np.cos(w + phi) + 0.02 * np.cos(2 * w + phi + 0.3) + 0.1
    y = 45.0 * np.cos(w + phi - 0.07) + 3.0 * np.cos(2 * w + 2 * phi + 1.1) + 0.5 * np.cos(3 * w - 0.4) + 175.0
    for arr, amp in ((x, 0.7), (y, 45.0)):
        arr += rng.normal(0.0, amp / np.sqrt(2 * 10 ** (snr_db / 10)), arr.shape)
    return x, y


def _coefficients(fit) -> np.ndarray:
    """A production fit's [offset, a_1, s_1, ...] (..., p), from its amplitudes and phases."""
    a, s = fit.amplitude * np.cos(fit.phase_rad), -fit.amplitude * np.sin(fit.phase_rad)
    return np.concatenate([np.asarray(fit.offset)[..., None], np.stack([a, s], axis=-1).reshape(a.shape[:-1] + (-1,))],
                          axis=-1)


def _assert_same_delay(new, x, y, fs: float, f: float, *, harmonic: int = 1, harmonics=(1,), exclude=None,
                       sigmas=estimation.OUTLIER_SIGMAS) -> None:
    """``new`` (a production PhaseDelay of records x, y, nominal frequency f) against the dense
    oracle, record by record."""
    batch, n = np.shape(x)[:-1], np.shape(x)[-1]
    masks = np.zeros((2,) + np.shape(x), bool) if exclude is None else np.stack(exclude)
    want = {k: np.zeros(batch) for k in ("delay", "delay_se", "freq", "freq_se")}
    coef, coef_se = np.zeros(batch + (2, 1 + 2 * len(harmonics))), np.zeros(batch + (2, 1 + 2 * len(harmonics)))
    noise, excluded = np.zeros(batch + (2,)), np.zeros(batch + (2, n), bool)
    for i in np.ndindex(batch):
        fit = dense.robust_fit(np.stack([x[i], y[i]]), fs, f, harmonics,
                               exclude=masks[(slice(None),) + i], sigmas=sigmas)
        want["delay"][i], want["delay_se"][i] = dense.phase_delay(fit, harmonics, harmonic)
        want["freq"][i], want["freq_se"][i] = fit.freq, np.sqrt(fit.cov[-1, -1])
        coef[i], noise[i], excluded[i] = fit.coef, np.sqrt(fit.sigma2), fit.mask
        coef_se[i] = np.sqrt(np.diag(fit.cov)[:-1]).reshape(2, -1)
    gap, se = np.abs(new.delay_s - want["delay"]), want["delay_se"]
    assert np.all(gap <= np.maximum(1e-9 * np.abs(want["delay"]), 1e-5 * se)), np.max(gap / se)
    # the search keeps a step only if sum log S does not grow; that sum is flat to its rounding over
    # ~1e-5 standard errors (seen: 2e-5 on 5 000 samples), where the oracle finds the derivative's root
    f_gap = np.abs(new.frequency_hz - want["freq"])
    assert np.all(f_gap <= np.maximum(1e-12 * want["freq"], 1e-4 * want["freq_se"])), np.max(f_gap / want["freq_se"])
    # standard errors: evaluated at those frequencies (an error is itself known to ~1/sqrt(2N) only);
    # on noiseless data they are the noise variance's rounding floor, known to its order only
    np.testing.assert_allclose(new.delay_se_s, want["delay_se"], rtol=1e-4, atol=1e-12 / (harmonic * f))
    np.testing.assert_allclose(new.frequency_se_hz, want["freq_se"], rtol=1e-4, atol=1e-12 * f)
    for c, fit in enumerate((new.x, new.y)):
        np.testing.assert_array_equal(fit.excluded, excluded[..., c, :])
        # rounding: relative to the value, or to the record's scale (noiseless data: se ~ eps)
        want_c, se_c = coef[..., c, :], coef_se[..., c, :]
        scale = np.max(np.abs(want_c), axis=-1, keepdims=True)
        gap = np.abs(_coefficients(fit) - want_c)
        assert np.all(gap <= np.maximum(1e-9 * np.maximum(np.abs(want_c), 1e-3 * scale), 1e-5 * se_c)), \
            np.max(gap / se_c)
        np.testing.assert_allclose(fit.noise_std, noise[..., c], rtol=1e-6, atol=1e-12 * np.max(scale))
        assert np.all(fit.converged)


@pytest.mark.acceptance  # the dense oracle on 300 000 samples; make test: 200 000 in the next test
@pytest.mark.parametrize("seed", [0, 1])
def test_a_long_record_with_glitches_gives_the_dense_delays_and_outliers(seed: int) -> None:
    # 300 000 samples: five blocks, and a search window wider than half a bin (the grid scan runs)
    x, y = _channels(300_000, seed)
    y[[7, 123_456, 299_999]] = (1e308, 2000.0, -300.0)  # gross, large, and one hidden by the others
    x[65_536] += 0.3
    kw = dict(harmonic=1, harmonics=HARMONICS)
    new = estimation.phase_delay(x, y, FS, 320.0, **kw)
    assert new.y.outliers.tolist() == [7, 123_456, 299_999] and new.x.outliers.tolist() == [65_536]
    _assert_same_delay(new, x, y, FS, 320.0, **kw)


def test_the_method_s_second_fits_with_exclusions_and_a_given_frequency() -> None:
    x, y = _channels(200_000, 2)
    drive = (x - x.mean()) ** 2  # the no-magnet reference: its 2f component
    ex_x, ex_y = np.zeros(x.size, bool), np.zeros(x.size, bool)
    ex_x[[10, 90_000]], ex_y[[5, 150_001, 150_002]] = True, True
    kw = dict(harmonic=2, harmonics=HARMONICS, exclude=(ex_x, ex_y), outlier_sigmas=None)
    _assert_same_delay(estimation.phase_delay(drive, y, FS, 320.013, **kw), drive, y, FS, 320.013, harmonic=2,
                       harmonics=HARMONICS, exclude=(ex_x, ex_y), sigmas=None)
    new = estimation.sine_fit(y, FS, 320.013, harmonics=HARMONICS, fit_freq=False, exclude=ex_y)
    ref = dense.robust_fit(y[None], FS, 320.013, HARMONICS, fit_freq=False, exclude=ex_y[None])
    phases = [ref.phase(0, j) for j in range(len(HARMONICS))]
    # to rounding: 1e-12 rad or a hundred-thousandth of the phase's standard error (the compiled
    # regressors, tests/analysis/estimation/test_lsq_kernel.py, round differently from numpy's cos)
    se = np.array([ref.se(grad) for _, grad in phases])
    np.testing.assert_array_less(np.abs(new.phase_rad - [phi for phi, _ in phases]), np.maximum(1e-12, 1e-5 * se))
    np.testing.assert_allclose(new.phase_se_rad, [ref.se(grad) for _, grad in phases], rtol=1e-9)
    np.testing.assert_array_equal(new.excluded, ref.mask[0])
    assert new.outliers.tolist() == [5, 150_001, 150_002]  # the exclusions; the noise has no outlier


@pytest.mark.parametrize(("batch", "n"), [((40,), 5_000), ((3, 140), 63)])
def test_batches_of_records_give_the_dense_delays(batch, n: int) -> None:
    x, y = _channels(n, 3, batch=batch, snr_db=30.0, fs=10_000.0)  # 63 samples: two periods
    x.reshape(-1, n)[::7, n // 3] += 50.0  # a glitch in every seventh record
    kw = dict(harmonics=(1, 2))
    new = estimation.phase_delay(x, y, 10_000.0, 320.0, **kw)
    assert np.array_equal(new.x.excluded.reshape(-1, n).any(axis=-1), np.arange(x.size // n) % 7 == 0)
    _assert_same_delay(new, x, y, 10_000.0, 320.0, **kw)


@pytest.mark.acceptance  # the dense oracle takes a minute on three long channels
def test_noiseless_records_and_find_outliers_across_three_channels() -> None:
    t = np.arange(150_000) / FS
    chans = [np.cos(2 * np.pi * 320.0071 * t + p) * a + dc for p, a, dc in ((0.1, 1.0, 0.0), (0.5, 0.02, 1.0),
                                                                              (-0.3, 40.0, 175.0))]
    kw = dict(harmonic=1, harmonics=HARMONICS)
    _assert_same_delay(estimation.phase_delay(chans[0], chans[1], FS, 320.0, **kw), chans[0], chans[1], FS, 320.0, **kw)
    chans[2] = chans[2] + np.random.default_rng(4).normal(0.0, 0.05, t.size)
    chans[2][[3, 77_777]] = (1e6, 176.0 + 40.0)
    new, f_new = estimation.find_outliers(chans, FS, 320.0, harmonics=HARMONICS)
    ref = dense.robust_fit(np.stack(chans), FS, 320.0, HARMONICS)
    assert [m.nonzero()[0].tolist() for m in new] == [m.nonzero()[0].tolist() for m in ref.mask] \
        == [[], [], [3, 77_777]]
    assert f_new == pytest.approx(ref.freq, rel=1e-12)


@pytest.mark.parametrize(("shape", "f"), [((400_000,), 320.0), ((25, 3_000), 640.0)])
def test_covariance_delay_gives_the_dense_lag(shape, f: float) -> None:
    n = shape[-1]
    x, y = _channels(n, 5, batch=shape[:-1], f=f)
    new = estimation.covariance_delay(x, y, FS, f)
    for i in np.ndindex(shape[:-1]):
        lag, cov, lags = dense.covariance_delay(x[i], y[i], FS, f)
        assert new.lag_samples[i] == lag and 0 < lag < 10  # y lags x by 0.07 rad: a fraction of a period
        np.testing.assert_array_equal(new.lags, lags)
        np.testing.assert_allclose(new.covariance[i], cov, rtol=1e-9)


@pytest.mark.parametrize(("n", "batch", "ks", "snr_db"), [pytest.param(1_000_000, (), (1, 2, 3, 4), 50.0, marks=pytest.mark.acceptance), (400_000, (), (2,), 0.0),
                                                       (200_000, (3,), (1, 2, 3, 4), 20.0)])
def test_the_start_frequency_scan_picks_the_dense_grid_point(n: int, batch, ks, snr_db: float) -> None:
    # the grid over +-200 ppm has ~N points; the chirp-z transform must rank them as the direct sums do
    x, y = _channels(n, 7, batch=batch, snr_db=snr_db)
    data = np.stack([x.reshape(-1, n), y.reshape(-1, n)], axis=1)
    mask = np.zeros(data.shape, bool)
    mask[:, 1, ::5000] = True  # left out: counted as the channel's median
    fill = np.median(data, axis=-1)
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
