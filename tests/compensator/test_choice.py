"""Issue 29: the best model is never worse than a simpler one.  ``best`` is chosen among every
description (Eq. 1, Eq. 6, the iron descriptions) on held-out recordings of the sweep, by the worst
shortfall from the best description, ties going to the simpler one.  Judged on the independent bench
(tests/independent_bench: code that shares nothing with hystbench), whose elliptic iron is the case
where the Preisach description used to lose to the paper's Eq. 6."""

from __future__ import annotations

import pytest

from hystbench.analysis.identification import fit_instrument, frequency_response
from hystbench.compensator import ModelSet, fit_models, force_error
from hystbench.compensator.choice import SIMPLICITY
from hystbench.compensator.sweeps import period_data, sweep_data
from hystbench.config import load_rig
from hystbench.formats.recording import read_sweep
from independent_bench.bench import BASELINE, write_bench_day
from independent_bench.family import fit_plan, voice_coil_plan, write_family_bench

pytestmark = pytest.mark.slow(25)  # ~25 s: handed to a worker before lighter files (tests/conftest.py)


def _identified(fit_folder, voice_coil_folder):
    """What a user of the bench does: the instrument from the voice coil, the models from the sweep."""
    instrument = fit_instrument(frequency_response(read_sweep(voice_coil_folder))).model
    rig, points = sweep_data(read_sweep(fit_folder))
    return fit_models(points, load_rig(rig), instrument)


@pytest.fixture(scope="module")
def elliptic_with_magnet(tmp_path_factory):
    sweeps = write_family_bench("ecore_pm~elliptic", tmp_path_factory.mktemp("ecore_pm_elliptic"))
    return sweeps, _identified(sweeps["fit"], sweeps["voicecoil"])


@pytest.mark.acceptance  # 50 s of fitting; the rule itself is tested by the tie below in make test
def test_every_description_is_judged_and_the_report_says_which_and_why(elliptic_with_magnet):
    _, models = elliptic_with_magnet
    choice = models.report["choice"]
    assert choice["failed"] == {}  # the Preisach fixed point converges on an iron not of its family
    assert list(choice["worst_held_out_accuracy_pct"]) == list(SIMPLICITY)
    judged = [set(acc) for acc in choice["held_out_accuracy_pct"].values()]
    assert all(j == judged[0] and j for j in judged)  # the same held-out recordings for every description
    assert choice["chosen"] in SIMPLICITY and choice["chosen"] in choice["why"]
    assert choice["largest_shortfall_pts"][choice["chosen"]] == min(choice["largest_shortfall_pts"].values()) or \
        "within the noise" in choice["why"]


@pytest.mark.acceptance
def test_best_is_as_good_as_the_best_description_on_unseen_recordings_of_elliptic_iron(elliptic_with_magnet):
    """The issue's case: elliptic loops with the magnet, where best (then Preisach) lost to Eq. 6 by
    up to 0.17 points.  Now best is within 0.01 points of Eq. 6 and Eq. 1 on every unseen recording, and
    above 99.9 %."""
    sweeps, models = elliptic_with_magnet
    for rec in read_sweep(sweeps["judge"]):
        p = period_data(rec)
        acc = {k: force_error(m, p, models.instrument)["accuracy_pct"] for k, m in models.models.items()}
        assert acc["best"] >= max(acc["paper"], acc["nonhysteretic"]) - 0.01, (rec.frequency_hz, rec.current_pp_a, acc)
        assert acc["best"] >= 99.9, (rec.frequency_hz, rec.current_pp_a, acc)


def test_where_eq6_is_exact_the_simpler_description_wins_the_tie(tmp_path):
    """A linear iron with a constant loss angle and no eddy currents delays the flux by one angle at
    every frequency and amplitude: Eq. 6 is then the exact description, a richer one can only tie
    with it, and the tie goes to Eq. 6."""
    effects = {k: v for k, v in BASELINE.items() if k != "lamination_eddy_currents"}
    effects["static_hysteresis"] = {"tan_delta": 0.15, "tan_delta_per_T": 0.0}
    write_bench_day(tmp_path / "fit", effects=effects, seed=5, periods=16, plan=fit_plan("ecore_pm"))
    write_bench_day(tmp_path / "vc", effects=effects, seed=6, periods=48, fs_hz=400e3, plan=voice_coil_plan())
    models = _identified(tmp_path / "fit", tmp_path / "vc")
    choice = models.report["choice"]
    assert choice["chosen"] == "paper", choice["why"]
    assert models["best"].kind == "best" and models["best"].name == "eq6_phase_delay"
    # the model file says so, and reads back the same model
    back = ModelSet.load(models.save(tmp_path / "models.json"))
    assert back.report["choice"]["chosen"] == "paper"
    assert back["best"] == models["best"]
