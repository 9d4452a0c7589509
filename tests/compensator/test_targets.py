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


def test_paper_model_without_magnet_reaches_the_papers_factor(judged):
    e = judged["ecore", 320.0, 1.27][1]
    assert e["nonhysteretic"]["max_abs_error_N"] / e["paper"]["max_abs_error_N"] >= 2.5


def test_paper_factor_with_magnet_is_out_of_reach_of_any_phase_delay_model(judged, models_pm):
    """The paper's 5x (with magnet, 320 Hz) is not reachable on this rig by Eq. 6: even the phase
    delay and quadratic coefficients fitted to the judged recording itself give under 5x; the
    fitted Eq. 6 gets most of what that bound allows."""
    p, e = judged["ecore_pm", 320.0, 1.4]
    eq1, eq6 = e["nonhysteretic"]["max_abs_error_N"], e["paper"]["max_abs_error_N"]
    bound = eq1 / phase_delay_bound_n(p, models_pm.instrument)
    assert bound < 5.0
    assert eq1 / eq6 >= 0.7 * bound
    assert eq1 / eq6 > 2.5  # still a clear gain over Eq. 1 at the amplitude theta was measured at
