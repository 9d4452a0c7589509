"""Minor loops between extrema that tie (a periodic B sampled at a whole number of samples per
period) and the Preisach iron's ``close_t``: return-point memory at the model's resolution."""

from __future__ import annotations

import numpy as np

from hystbench.config import load_material
from hystbench.physics.hysteresis import PreisachHysteresis


def test_loops_between_tied_extrema_return_to_the_same_point():
    """40 periods of a biased sine whose amplitude shrinks by 1 nT a period (ties, as a sampled
    periodic B gives): return-point memory (Mayergoyz) says each loop ends where the last began, so
    H at the peaks changes only by dH/dB x 40 nT (< 1e-4 A/m).  The tabulated branches close a loop
    to ~1e-3 A/m only, so without closing ties each period nests one level deeper and drifts."""
    iron = PreisachHysteresis.from_config(load_material("M130-27S"))
    n, periods = 250, 40
    k = np.arange(n * periods)
    b = 0.6 + (0.27 - 1e-9 * (k // n)) * np.sin(2 * np.pi * (k + 0.5) / n)  # two samples at each extremum
    b = np.concatenate((np.linspace(0.0, 0.6, 100), b))
    h, state = iron.field(b, iron.initial_state(), close_t=1e-6)
    loops = h[100:].reshape(periods, n)
    assert np.ptp(loops.max(axis=1)) < 1e-4 and np.ptp(loops.min(axis=1)) < 1e-4
    assert len(state.turns) <= 2  # the major reversal and the latest one: no nest
    # close_t = 0 (the default) keeps the exact wiping-out rule: the same H wherever no tie is near
    plain, _ = iron.field(b[:100 + n], iron.initial_state())
    tied, _ = iron.field(b[:100 + n], iron.initial_state(), close_t=1e-6)
    assert np.array_equal(plain, tied)
