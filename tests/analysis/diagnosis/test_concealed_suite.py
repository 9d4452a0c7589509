"""Issue 13's targets on the concealed-effect suite (hystbench/sim_backend/concealed.py), each case a
bench day as the issue describes it.  The diagnosis sees the recordings and the baseline, never the
truth; these tests compare its answer with the generator's truth: the effect named (top 1), its
parameters against the values the generator used, every null case "none" (foreign benches
included), and the held-out improvement where an effect is present.

The whole suite is diagnosed once per session, one case per core (benchmarks/bench_diagnose.py's
judge, the same one `hystbench bench diagnose` prints); each test then reads its case's row.
"""

from __future__ import annotations

import math
import multiprocessing
import os
from concurrent.futures import ProcessPoolExecutor

import pytest

from benchmarks.bench_diagnose import TARGETS, run_named
from hystbench.sim_backend.concealed import CASES

pytestmark = pytest.mark.slow

#: What the diagnosis gets wrong, per check and case, with the reason (the closing note of issue 13 and
#: the README say the same).  Strict: a case that starts passing fails here until it is taken off.
_ABSORBED = ("a rate-independent change of the loop: the static loop's recalibration (which a bench that "
             "is not its simulation needs) absorbs it")
KNOWN_WRONG: dict[tuple[str, str], str] = {
    ("named", "load_cell_compliance"): _ABSORBED + ", with the core's geometry (a gap closed by F/k)",
    ("parameters", "load_cell_compliance"): "not named",
    ("improvement", "load_cell_compliance"): "not named",
    ("named", "iron_saturation"): _ABSORBED,
    ("parameters", "iron_saturation"): "not named",
    ("improvement", "iron_saturation"): "not named",
    ("named", "highpass+flux_skew"): ("the flux skew, second after the high-pass, scores but does not predict "
                                      "the held-out frequencies 1.5x better"),
    ("parameters", "highpass+flux_skew"): "the flux skew is not named",
    ("parameters", "foreign_m130_flux_skew"): ("on M130-27S the iron's own eddy lag differs from the preset's in a "
                                               "way that adds to the skew: 5.8 +- 0.2 us for 3 us"),
    ("improvement", "foreign_rayleigh_drift"): ("the Rayleigh iron's mismatch dominates the held-out residual: "
                                                "the drift is named but improves it 4x"),
}

#: A named parameter must be within this many standard errors of the generator's value, or this share
#: of it (the replay is the generator's own simulation, so the fit's error is noise and linearisation).
WITHIN_STD, WITHIN_SHARE = 4.0, 0.1


@pytest.fixture(scope="module")
def suite() -> dict[str, dict]:
    jobs = max(1, int(os.environ.get("HYSTBENCH_JOBS", 0)) or (os.cpu_count() or 1))
    with ProcessPoolExecutor(jobs, mp_context=multiprocessing.get_context("forkserver")) as pool:
        rows = list(pool.map(run_named, [c.name for c in CASES]))
    return {r["case"]: r for r in rows}


def _case(check: str, name: str):
    reason = KNOWN_WRONG.get((check, name))
    return pytest.param(name, marks=[pytest.mark.xfail(strict=True, reason=reason)] if reason else [], id=name)


@pytest.mark.parametrize("name", [_case("null", c.name) for c in CASES if c.null])
def test_a_null_case_names_nothing(suite, name):
    assert suite[name]["named"] == [], suite[name]


@pytest.mark.parametrize("name", [_case("named", c.name) for c in CASES if not c.null])
def test_the_effect_left_out_is_named(suite, name):
    row = suite[name]
    assert row["effect"] in row["truth"], row  # top 1
    assert set(row["truth"]) <= set(row["named"]), row  # two-effect cases: both, by forward selection


@pytest.mark.parametrize("name", [_case("parameters", c.name) for c in CASES if not c.null])
def test_the_named_effects_parameters_are_the_generators(suite, name):
    row = suite[name]
    for effect, expected in row["expected"].items():
        fitted = row["parameters"][effect]
        for param, truth in expected.items():
            if param not in fitted or truth == 0:  # a parameter the fit does not take, or a channel without skew
                continue
            value, std = fitted[param]["value"], fitted[param]["std"]
            assert value is not None and math.isfinite(value), (effect, param, fitted)
            err = abs(value - truth)
            assert err <= max(WITHIN_STD * (std or 0.0), WITHIN_SHARE * abs(truth)), (effect, param, value, std, truth)


@pytest.mark.parametrize("name", [_case("improvement", c.name) for c in CASES if not c.null])
def test_the_held_out_fit_improves_where_an_effect_is_present(suite, name):
    assert suite[name]["improvement"] >= TARGETS["improvement_x"], suite[name]


def test_the_suite_meets_the_naming_target(suite):
    effect_cases = [r for r in suite.values() if r["truth"]]
    right = sum(r["effect"] in r["truth"] for r in effect_cases)
    assert right / len(effect_cases) >= TARGETS["named_right_pct"] / 100.0, (right, len(effect_cases))
