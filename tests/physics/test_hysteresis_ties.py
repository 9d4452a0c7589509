"""Minor loops between extrema that tie (a periodic B sampled at a whole number of samples per
period): return-point memory holds to rounding, not to the tabulated branches' error."""

from __future__ import annotations

import numpy as np

from hystbench.config import load_material
from hystbench.physics.hysteresis import PreisachHysteresis


def test_loops_between_tied_extrema_return_to_the_same_point():
    """40 periods of a biased sine whose amplitude shrinks by 1 nT a period (ties, as a sampled
    periodic B gives): return-point memory (Mayergoyz) says each loop ends where the last began, so
    H at the peaks changes only by dH/dB x 40 nT (< 1e-4 A/m).  The tabulated branches alone close
    a loop to ~1e-3 A/m, so each period, nested one level deeper, would drift by that much; each
    branch is closed onto its turning point, so it does not.  The nest itself is physics: a
    shrinking amplitude leaves every extremum in the memory (two turns a period)."""
    iron = PreisachHysteresis.from_config(load_material("M130-27S"))
    n, periods = 250, 40
    k = np.arange(n * periods)
    b = 0.6 + (0.27 - 1e-9 * (k // n)) * np.sin(2 * np.pi * (k + 0.5) / n)  # two samples at each extremum
    b = np.concatenate((np.linspace(0.0, 0.6, 100), b))
    h, state = iron.field(b, iron.initial_state())
    loops = h[100:].reshape(periods, n)
    assert np.ptp(loops.max(axis=1)) < 1e-4 and np.ptp(loops.min(axis=1)) < 1e-4
    assert len(state.turns) == 2 * periods
    # a larger excursion wipes the whole nest out: the state is that of the major reversal alone
    _, after = iron.field(np.linspace(b[-1], 0.95, 200), state)
    assert len(after.turns) <= 1
