"""The closed loop on the simulated rig: learning reaches the noise floor; the guard stops itself."""

import numpy as np
import pytest

from hystbench.compensator import (CompensatorError, ForceReference, LearningConfig, LearningStopped, NonHysteretic,
                                   RigActuation, StaticLaw, UnreachableReference, run_closed_loop)
from hystbench.drivers.protocols.bench_config import load_bench_config
from hystbench.sim_backend.rig import SimulatedRig


def actuation(rig, f, **kw):
    return RigActuation(SimulatedRig(rig, seed=7, frequency_hz=f, **kw), load_bench_config().current_limit_a)


@pytest.mark.parametrize("rig, spec, start", [
    ("ecore_pm", "offset=170,amp=40,freq=320", {"current_pp_a": 0.0}),  # from rest
    ("ecore_pm", "offset=170,amp=40,freq=320", {}),  # after the preset's 1.4 A-pp sine: the iron remembers
    ("ecore", "offset=2,amp=1,freq=320", {"current_pp_a": 0.0}),
])
def test_learning_reaches_twice_the_noise_floor_within_ten_iterations(request, rig, spec, start):
    models = request.getfixturevalue("models_pm" if rig == "ecore_pm" else "models_ecore")
    ref = ForceReference.parse(spec)
    res = run_closed_loop(actuation(rig, 320.0, **start), models["best"], ref, models.instrument,
                          config=LearningConfig(iterations=10))
    ratios = [r.ratio for r in res.history]
    assert res.reached_at is not None and res.reached_at <= 10, ratios
    assert ratios[-1] <= 2.0 and max(ratios[res.reached_at:]) <= 2.5, ratios
    assert res.history[-1].noise_floor_n < (0.05 if rig == "ecore_pm" else 0.003)  # the paper's sensor noise, averaged
    assert res.history[0].iteration == 0 and len(res.history) == 11


def test_feed_forward_alone_is_already_close_from_rest(models_pm):
    ref = ForceReference.parse("offset=170,amp=40,freq=320")
    res = run_closed_loop(actuation("ecore_pm", 320.0, current_pp_a=0.0), models_pm["best"], ref,
                          models_pm.instrument, learn=False)
    assert len(res.history) == 1
    assert res.history[0].error_pct < 0.1  # below 0.1 % of the reference's range with no learning


def test_a_diverging_loop_stops_itself_and_switches_the_output_off(models_pm):
    """A model four times too weak (the wrong model file): each learning step overshoots 3.2x, so
    the error grows; the guard stops the loop, the output goes off, and the reason is given."""
    law = models_pm["nonhysteretic"].law
    wrong = NonHysteretic(StaticLaw(law.k0_n, law.k1_n_per_a / 4, law.k2_n_per_a2 / 4, magnet=True))
    inner = actuation("ecore_pm", 320.0, current_pp_a=0.0)
    with pytest.raises(LearningStopped, match="diverging: the tracking error grew to .* N, more than 2x the best") as err:
        run_closed_loop(inner, wrong, ForceReference.parse("offset=175,amp=2,freq=320"), models_pm.instrument,
                        config=LearningConfig(iterations=10))
    assert not inner.output_on
    hist = err.value.history
    assert 2 <= len(hist) <= 4 and hist[-1].max_error_n > 2 * hist[0].max_error_n


def test_unreachable_references_and_current_limit(models_pm, models_ecore):
    with pytest.raises(UnreachableReference, match="only attracts"):
        run_closed_loop(actuation("ecore", 320.0), models_ecore["best"], ForceReference.parse("offset=0,amp=1,freq=320"),
                        models_ecore.instrument)
    with pytest.raises(UnreachableReference, match=r"above the 1.71 A limit; reachable 7\d.\d+ to 3\d\d.\d+ N"):
        run_closed_loop(actuation("ecore_pm", 320.0), models_pm["best"],
                        ForceReference.parse("offset=200,amp=150,freq=320"), models_pm.instrument)
    act = actuation("ecore_pm", 320.0)
    with pytest.raises(CompensatorError, match="refused a 4-point waveform: peak 2.5 A exceeds the 1.71 A limit"):
        act.set_waveform(np.array([0.0, 2.5, 0.0, -1.0]), 320.0)
    with pytest.raises(CompensatorError, match="exceeds the 1.71 A limit"):
        act.set_sine(320.0, 3.0, 0.5)
