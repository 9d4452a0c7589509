"""Issue 6's open-loop targets, on the simulated rig with noise at the paper's level.

The models are fitted once on the identification sweep (conftest: 40, 160, 480 Hz x 0.3-1.5 A-pp,
seed 1000) and judged here on recordings they were not fitted on: other seeds, 80 and 320 Hz
(frequencies the fit did not see), and 0.9 A-pp and the paper's amplitudes (amplitudes it did
not see).  Accuracy = 100 % (1 - max|F_measured - H_instr{F_model}| / range) on the period average.
"""

import pytest

from hystbench.compensator import force_error
from hystbench.compensator.models import phase_delay_bound_n

MAIN = {"ecore": 1.27, "ecore_pm": 1.4}


@pytest.fixture(scope="module")
def judged(models_pm, models_ecore, unseen):
    out = {}
    for rig, ms in (("ecore", models_ecore), ("ecore_pm", models_pm)):
        for n, f in enumerate((40.0, 80.0, 160.0, 320.0, 480.0)):
            for ipp in (MAIN[rig], 0.9):
                p = unseen(rig, f, ipp, seed=5000 + 10 * n + (ipp == 0.9))
                out[rig, f, ipp] = (p, {k: force_error(m, p, ms.instrument) for k, m in ms.models.items()})
    return out


@pytest.mark.parametrize("rig", ["ecore", "ecore_pm"])
def test_best_model_predicts_within_a_thousandth_at_40_to_480_hz(judged, rig):
    acc = {(f, ipp): e["best"]["accuracy_pct"] for (r, f, ipp), (_, e) in judged.items() if r == rig}
    assert len(acc) == 10
    assert min(acc.values()) >= 99.9, acc
    assert all(judged[rig, f, ipp][1]["nonhysteretic"]["accuracy_pct"] < 99.2 for f, ipp in acc)  # not trivial


@pytest.mark.parametrize("rig", ["ecore", "ecore_pm"])
def test_best_model_cuts_the_non_hysteretic_error_tenfold_at_320_hz(judged, rig):
    e = judged[rig, 320.0, MAIN[rig]][1]
    assert e["nonhysteretic"]["max_abs_error_N"] / e["best"]["max_abs_error_N"] >= 10.0
    e = judged[rig, 320.0, 0.9][1]
    assert e["nonhysteretic"]["max_abs_error_N"] / e["best"]["max_abs_error_N"] >= 10.0


@pytest.mark.parametrize("rig, main", [("ecore", 1.27), ("ecore_pm", 1.4)])
def test_paper_model_on_our_preisach_iron_gains_within_its_bound(judged, models_pm, models_ecore, rig, main):
    """Our rigs' iron is a Preisach one: its loops are not ellipses and its effective permeability
    changes with amplitude, so one static law for the sweep and one delay per frequency (Eq. 6)
    fall short of the paper's factors here; those are held where the iron's loops are elliptic
    (tests/compensator/test_foreign_benches.py).  Here Eq. 6 still cuts Eq. 1's error, and no
    phase-delay model could beat the bound (delay and law fitted to the judged recording itself)."""
    p, e = judged[rig, 320.0, main]
    ms = models_pm if rig == "ecore_pm" else models_ecore
    eq1, eq6 = e["nonhysteretic"]["max_abs_error_N"], e["paper"]["max_abs_error_N"]
    bound = eq1 / phase_delay_bound_n(p, ms.instrument)
    assert 1.3 < eq1 / eq6 < bound
