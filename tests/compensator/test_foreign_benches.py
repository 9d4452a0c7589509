"""Issue 12: the models hold on benches that are not our simulated rig.

Each foreign bench (``sim_backend.benches``: geometry, turns, magnet and airgap off by up to 20 %,
another iron, the instrument off its nominal values) is identified the way a user would: the
instrument with the ferrite voice coil on its load cell (paper Sec. IV), then the force models from
the identification sweep (40, 160, 480 Hz x 0.3-1.5 A-pp), starting from the NOMINAL preset, which
is all a user of that bench would have.  They are judged on recordings the fit never saw (other
seeds, 80 and 320 Hz, 0.9 A-pp and the paper's amplitude).  Expected values come from the
generator's truth (``bench_truth``) or the paper, never from a model's own output.
"""

import pytest

from hystbench.compensator import ForceReference, LearningConfig, RigActuation, force_error, run_closed_loop
from hystbench.drivers.protocols.bench_config import load_bench_config
from hystbench.compensator.sweeps import period_data, quick_instrument, quick_models
from hystbench.sim_backend.benches import FOREIGN_BENCHES, bench_truth, foreign_preset
from hystbench.sim_backend.recordings import simulated_sweep
from hystbench.sim_backend.rig import SimulatedRig

pytestmark = pytest.mark.slow(20)  # ~20 s: handed to a worker before lighter files (tests/conftest.py)

MAIN = {"ecore": 1.27, "ecore_pm": 1.4}
#: the bench make test fits (the choice of a Preisach iron is make test's on our own rig, test_models);
#: every other bench runs with ``-m acceptance`` (.ci/run), each fit costing 10-40 s
IN_SUITE = ("ecore~elliptic",)


def benches(names):
    """``names`` as parameters, those outside IN_SUITE marked acceptance."""
    return [n if n in IN_SUITE else pytest.param(n, marks=pytest.mark.acceptance) for n in names]
PAPER_FACTOR = {"ecore": 2.5, "ecore_pm": 5.0}  # Eq. 6 at 320 Hz (paper Sec. VII)
_FITTED: dict = {}


def fitted(name: str):
    """(models, judged {(f, ipp): (point, errors per model)}) of one bench, computed once."""
    if name not in _FITTED:
        bench = FOREIGN_BENCHES[name]
        preset = foreign_preset(name)
        models = quick_models(bench.nominal, bench=preset, instrument=quick_instrument(preset))
        judged = {}
        for n, f in enumerate((80.0, 320.0)):
            for ipp in (MAIN[bench.nominal], 0.9):
                rec = simulated_sweep(preset, [f], [ipp], seed=5000 + 10 * n + (ipp == 0.9), duration_s=0.5)[0]
                p = period_data(rec)
                judged[f, ipp] = (p, {k: force_error(m, p, models.instrument) for k, m in models.models.items()})
        _FITTED[name] = (models, judged)
    return _FITTED[name]


@pytest.mark.parametrize("name", benches(FOREIGN_BENCHES))
def test_best_model_predicts_a_foreign_bench_within_a_thousandth(name):
    models, judged = fitted(name)
    acc = {k: e["best"]["accuracy_pct"] for k, (_, e) in judged.items()}
    assert min(acc.values()) >= 99.9, (models.report["choice"]["why"], acc)
    for _, e in judged.values():  # and beats Eq. 1 (by little on the low-loss M130-27S: theta_hyst 0.2 deg)
        assert e["nonhysteretic"]["max_abs_error_N"] > 1.3 * e["best"]["max_abs_error_N"]


@pytest.mark.parametrize("name", benches(n for n in FOREIGN_BENCHES if n.endswith("~elliptic")))
def test_eq6_reaches_the_papers_factor_where_the_minor_loops_are_elliptic(name):
    """The paper's iron has nearly elliptic minor loops (Fig. 4), and there Eq. 6 with the measured
    delay cuts Eq. 1's error 2.5x without and 5x with the magnet at 320 Hz (Sec. VII)."""
    nominal = FOREIGN_BENCHES[name].nominal
    _, judged = fitted(name)
    e = judged[320.0, MAIN[nominal]][1]
    assert e["nonhysteretic"]["max_abs_error_N"] / e["paper"]["max_abs_error_N"] >= PAPER_FACTOR[nominal]


@pytest.mark.parametrize("name, chosen", [("ecore~elliptic", "describing_function"),
                                          pytest.param("ecore_pm~m330", "preisach", marks=pytest.mark.acceptance),
                                          pytest.param("ecore_pm~elliptic", "describing_function",
                                                       marks=pytest.mark.acceptance),
                                          pytest.param("ecore~m330", "preisach", marks=pytest.mark.acceptance)])
def test_the_sweep_chooses_the_iron_description_the_bench_has(name, chosen):
    """Elliptic loops are one complex gain per harmonic exactly; a Preisach iron's pointed loops
    are not: held-out error inside the fit sweep tells them apart, and the report says why."""
    from hystbench.compensator.choice import SIMPLICITY

    models, _ = fitted(name)
    choice = models.report["choice"]
    assert choice["chosen"] == chosen, choice["why"]
    # every description was judged on the same held-out recordings, and the report shows it
    judged = [set(acc) for acc in choice["held_out_accuracy_pct"].values()]
    assert len(judged) + len(choice["failed"]) == len(SIMPLICITY) and len(judged) >= 2
    assert all(j == judged[0] and j for j in judged)


@pytest.mark.parametrize("name", benches(["ecore_pm~elliptic", "ecore~elliptic"]))
def test_identified_static_law_is_the_benchs_not_the_presets(name):
    """On a linear (complex-permeability) iron the static law of Eq. 6 is the MEC with the iron's
    in-phase permeability at the bench's own geometry: the fit finds it within 3 %, although the
    preset it started from is 5-20 % off."""
    models, _ = fitted(name)
    truth = bench_truth(name)["force_coefficients_linear_iron"]
    nominal = FOREIGN_BENCHES[name].nominal
    k0, k1, k2 = models["paper"].law.coefficients
    assert k2 == pytest.approx(truth[2], rel=0.03)
    if nominal == "ecore_pm":  # without a magnet k0 and k1 are zero by the law's form
        assert k1 == pytest.approx(truth[1], rel=0.03)
        assert k0 == pytest.approx(truth[0], rel=0.03)


@pytest.mark.parametrize("name", benches(FOREIGN_BENCHES))
def test_learning_reaches_twice_the_noise_floor_on_a_foreign_bench(name):
    """From rest, feed-forward from the fitted best model then learning on the measured,
    instrument-corrected error: within 2x the averaged force's noise floor in <= 10 iterations."""
    from benchmarks.bench_compensator import foreign_reference

    models, _ = fitted(name)
    nominal = FOREIGN_BENCHES[name].nominal
    ref = ForceReference.parse(foreign_reference(models, nominal))
    act = RigActuation(SimulatedRig(foreign_preset(name), seed=7, frequency_hz=ref.frequency_hz, current_pp_a=0.0),
                       load_bench_config().current_limit_a)
    res = run_closed_loop(act, models["best"], ref, models.instrument, config=LearningConfig(iterations=10))
    ratios = [r.ratio for r in res.history]
    assert res.reached_at is not None and res.reached_at <= 10, ratios
    assert ratios[-1] <= 2.0, ratios


@pytest.mark.parametrize("name", benches(["ecore~elliptic", "ecore~rayleigh"]))
def test_each_iron_description_inverts_itself_and_survives_its_model_file(name, tmp_path):
    """The describing function and the Rayleigh loops: the feed-forward (force -> current) and the
    prediction (current -> force) are inverses, and a model file written and read back predicts the same."""
    import numpy as np

    from hystbench.compensator import ModelSet, predict_measured

    models, _ = fitted(name)
    best = models["best"]
    assert best.name in ("describing_function", "rayleigh_loop")
    ref = ForceReference.parse("offset=2,amp=1,freq=320,h2=0.2@30")
    i = best.current_period(ref.force_n, ref.frequency_hz)
    assert best.force_period(i, ref.frequency_hz) == pytest.approx(ref.force_n, abs=1e-6 * 3.0)
    back = ModelSet.load(models.save(tmp_path / "m.json"))
    assert back["best"].name == best.name
    a = predict_measured(best, i, 320.0, models.instrument)
    b = predict_measured(back["best"], i, 320.0, back.instrument)
    assert np.max(np.abs(a - b)) < 1e-9
