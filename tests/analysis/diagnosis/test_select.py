"""What a candidate claims, where the held-out proof judges it (select.contribution, claimed=True)."""

import numpy as np

from hystbench.analysis.diagnosis.fit import Column, solve
from hystbench.analysis.diagnosis.select import CandidateEffect, contribution

SIGMA = 0.01


def fitted(strength_a: float, noise_at_60: float):
    """An effect with two parameters: ``a`` moves numbers 0-49, ``b`` moves number 60 alone, where the
    data hold only noise (``noise_at_60`` sigmas): b is fitted at that, +- one sigma."""
    d = np.zeros(80)
    d[:50] = strength_a
    d[60] = noise_at_60 * SIGMA
    a = Column("eff.a", np.r_[np.ones(50), np.zeros(30)])
    b = Column("eff.b", np.eye(80)[60])
    eff = CandidateEffect("eff", [a, b])
    return eff, solve(d, np.full(80, SIGMA), eff.columns)


def test_a_parameter_fitted_at_nothing_claims_nothing():
    """b at 0.9 sigma moves number 60 by 0.9 sigma: the fitted contribution would put it in the proof,
    the claim does not (|b| < 2 SE); a's numbers are all there."""
    eff, sol = fitted(0.05, 0.9)
    where = np.abs(contribution(eff, sol, claimed=True)) >= 0.5 * SIGMA
    everything = sum(sol.value(c.name)[0] * c.values for c in eff.columns)
    assert np.abs(everything[60]) >= 0.5 * SIGMA  # what the old mask judged
    assert np.all(where[:50]) and not where[60] and not np.any(where[50:])


def test_a_significant_parameter_is_claimed_and_with_none_significant_all_are():
    eff, sol = fitted(0.05, 3.0)  # b at 3 sigma: a claim
    assert (np.abs(contribution(eff, sol, claimed=True)) >= 0.5 * SIGMA)[60]
    eff, sol = fitted(0.0005, 0.9)  # a at 0.05 sigma of a 50-number mean (0.35 SE), b at 0.9: neither
    claim = contribution(eff, sol, claimed=True)
    assert claim[60] == sol.value("eff.b")[0] and claim[0] == sol.value("eff.a")[0]
