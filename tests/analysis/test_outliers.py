"""Gross outliers (issue 10): one glitched sample must neither move a delay nor pass silently.

The glitches of the issue, injected into simulated recordings: one force sample of 1e6 N (gave an
instrument delay of -22 deg and exit 0), one of 2000 N (moved the instrument phase silently), one
of 1e308 (was called clipping).  Each is found at its exact index, reported, and left out: the
delays equal the clean recording's."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from hystbench.cli.main import main
from hystbench.analysis.estimation import phase_delay, sine_fit
from hystbench.analysis.method import estimate, measure_delays
from hystbench.acquisition.pipeline import Pipeline
from hystbench.formats.recording import Recording, write_recording
from hystbench.acquisition.stages import WindowEstimator
from hystbench.blocks import SampleBlock
from hystbench.errors import EstimationError
from hystbench.sim_backend.rig import SimulatedRig

NAMES = ("hysteresis", "instrument", "total")


def simulate(rig: str = "ecore_pm", f: float = 320.0, seconds: float = 0.1, seed: int = 1) -> Recording:
    sim = SimulatedRig(rig, frequency_hz=f, seed=seed)
    return Recording("bench/run_0042", sim.fs_hz, dict(sim.record(seconds).channels), sim.metadata())


def glitched(rec: Recording, **glitches: list[tuple[int, float]]) -> Recording:
    channels = {c: x.copy() for c, x in rec.channels.items()}
    for c, hits in glitches.items():
        for i, v in hits:
            channels[c][i] = v
    return Recording(rec.path, rec.fs_hz, channels, dict(rec.metadata))


@pytest.fixture(scope="module", params=["ecore_pm", "ecore"])
def clean(request):
    rec = simulate(request.param)
    return rec, measure_delays(rec)


@pytest.mark.parametrize("value", [1e6, 2000.0, -2000.0, 1e308])
def test_one_glitch_is_found_reported_and_left_out(clean, value: float) -> None:
    rec, ref = clean
    d = measure_delays(glitched(rec, force_N=[(4321, value)]))
    assert d.outliers == {"force_N": [4321]}
    for k in NAMES:  # the clean recording's delays, to a small part of their standard error
        assert abs(d.delays_s[k] - ref.delays_s[k]) < 0.1 * ref.delays_std_s[k], k
        assert d.delays_std_s[k] == pytest.approx(ref.delays_std_s[k], rel=0.01)
    assert d.as_dict()["outliers_excluded"] is True


def test_glitches_in_every_channel_each_reported_exactly(clean) -> None:
    rec, ref = clean
    amp = {c: float(np.ptp(rec.channels[c])) for c in ("current_A", "flux_Wb", "force_N")}
    hits = {"current_A": [(17, 3 * amp["current_A"])], "flux_Wb": [(5000, -2 * amp["flux_Wb"]), (9000, 1e30)],
            "force_N": [(0, 1e6), (rec.n - 1, -1e6), (6000, 2000.0)]}
    d = measure_delays(glitched(rec, **hits))
    assert d.outliers == {c: sorted(i for i, _ in v) for c, v in hits.items()}
    for k in NAMES:
        assert abs(d.delays_s[k] - ref.delays_s[k]) < 0.2 * ref.delays_std_s[k], k


def test_a_1e308_sample_is_an_outlier_not_clipping() -> None:
    rec = glitched(simulate(), force_N=[(1234, 1e308)])
    out = estimate(rec)  # before: "channel 'force_N' looks clipped: 100.0 % of its samples sit at ..."
    assert out["outliers"] == {"force_N": [1234]} and out["outliers_excluded"] is True
    assert math.isfinite(out["covariance_method"]["delays_s"]["instrument"])
    json.dumps(out)  # and the JSON carries them


def test_a_channel_of_absurd_size_is_refused_naming_it() -> None:
    """A whole channel at 1e157 (a scale gone wrong) is no glitch: it overflowed the fits' sums of squares
    (a traceback); refused, naming the channel and its size."""
    rec = simulate()
    rec.channels["current_A"] = rec.channels["current_A"] * 1e157
    with pytest.raises(EstimationError, match=r"channel 'current_A' reaches .*e\+15\d apart from its outliers"):
        estimate(rec)


def test_a_channel_too_small_for_the_fits_is_refused_naming_it(clean) -> None:
    """A channel scaled to 1e-200 (its squares underflow) ended in "Singular matrix"; it is refused,
    naming the channel and its swing.  At 1e-20 the delays are the same: they do not depend on a scale."""
    rec, ref = clean

    def scaled(k: float) -> Recording:
        return Recording(rec.path, rec.fs_hz, {**rec.channels, "flux_Wb": rec.channels["flux_Wb"] * k}, dict(rec.metadata))

    with pytest.raises(EstimationError, match=r"channel 'flux_Wb' swings by .*e-20\d apart from its outliers"):
        estimate(scaled(1e-200))
    d = measure_delays(scaled(1e-20))
    for k in NAMES:
        assert abs(d.delays_s[k] - ref.delays_s[k]) < 0.01 * ref.delays_std_s[k], k


def test_clean_recordings_have_no_outliers(clean) -> None:
    rec, ref = clean
    assert ref.outliers == {} and ref.as_dict()["outliers_excluded"] is False


def test_gaussian_noise_over_a_million_samples_never_trips_it() -> None:
    """At 9 robust sigmas the chance per sample is 2e-19: a million samples of noise give none."""
    fs, f = 100_000.0, 320.0
    rng = np.random.default_rng(20130705)
    t = np.arange(1_000_000) / fs
    x = 0.7 * np.sin(2 * np.pi * f * t) + 0.01 * rng.standard_normal(t.size)
    y = 45 * np.sin(2 * np.pi * f * (t - 1e-5)) + 175 + 0.03 * rng.standard_normal(t.size)
    r = phase_delay(x, y, fs, f)
    assert r.x.outliers.size == 0 and r.y.outliers.size == 0
    y[123_456] += 50 * 0.03  # 50 sigmas: found, and only that one
    assert sine_fit(y, fs, f).outliers.tolist() == [123_456]


def test_too_many_outliers_is_a_broken_channel() -> None:
    rec = simulate()
    rng = np.random.default_rng(3)
    idx = rng.choice(rec.n, size=rec.n // 50, replace=False)  # 2 % of the samples
    with pytest.raises(EstimationError, match=r"run_0042.*'flux_Wb'.*broken"):
        measure_delays(glitched(rec, flux_Wb=[(int(i), 1.0) for i in idx]))


def test_flat_apart_from_a_glitch_is_flat() -> None:
    rec = simulate()
    rec.channels["current_A"] = np.zeros(rec.n)
    rec.channels["current_A"][99] = 1.0
    with pytest.raises(EstimationError, match=r"run_0042.*'current_A'.*flat"):
        measure_delays(rec)


def test_a_channel_the_fit_explains_too_little_of_is_refused() -> None:
    """A force channel that is mostly noise, its weak 320 Hz component still the spectrum's peak:
    the old check let it through (peak where expected); below 5 % explained it is refused."""
    rec = simulate(seconds=0.2)
    rng = np.random.default_rng(4)
    f = rec.channels["force_N"]
    weak = 175 + 0.02 * (f - f.mean()) + 3.0 * rng.standard_normal(rec.n)  # 0.9 N amplitude in 3 N noise
    rec.channels["force_N"] = weak
    with pytest.raises(EstimationError, match=r"run_0042.*'force_N'.*explains only"):
        measure_delays(rec)


def test_cli_names_the_outliers_on_stderr_and_in_the_json(tmp_path, capsys) -> None:
    rec = glitched(simulate(), force_N=[(4321, 1e6)])
    write_recording(rec, tmp_path / "run")
    assert main(["estimate", str(tmp_path / "run"), "--json"]) == 0
    cap = capsys.readouterr()
    assert json.loads(cap.out)["outliers"] == {"force_N": [4321]}
    assert "force_N at 4321" in cap.err and "outlier" in cap.err


def test_the_live_estimator_names_outliers_by_source_index_and_reports_them() -> None:
    """In the pipeline: the estimate of the window holding the glitch names it by its index in the
    stream, the delays are unmoved, and a status warning says so."""
    rec = simulate(seconds=0.6)
    stream = glitched(rec, force_N=[(40_000, 1e6)])
    blocks = [SampleBlock(i, rec.fs_hz, {c: x[i:i + 1000].astype(np.float32) for c, x in stream.channels.items()},
                          meta={"frequency_hz": 320.0, "current_pp_a": rec.current_pp_a, "offset_a": 0.0,
                                "output_on": 1.0, "table": 0.0})
              for i in range(0, rec.n, 1000)]

    class Replay:
        name, channels, fs_hz, pace = "glitched", list(stream.channels), rec.fs_hz, "max"

        def metadata(self):
            return dict(rec.metadata)

        def blocks(self, stop=None):
            return iter(blocks)

        def close(self):
            pass

    pipe = Pipeline(Replay(), estimator=WindowEstimator(rec.fs_hz, rec.metadata, min_hop_s=0.0))
    got = []
    pipe.listeners.append(lambda t, o: got.append((t, o)))
    pipe.start()
    assert pipe.join(60) and pipe.error is None
    ests = [o for t, o in got if t == "/estimate"]
    hit = [e for e in ests if e["first_index"] <= 40_000 < e["end_index"]]
    assert hit and all(e["outliers"] == {"force_N": [40_000]} and e["error"] is None for e in hit)
    assert all(e["outliers"] == {} for e in ests if e not in hit)
    others = [e["phases_deg"]["instrument"] for e in ests if e not in hit]
    se = np.mean([e["phases_std_deg"]["instrument"] for e in ests])
    assert all(abs(e["phases_deg"]["instrument"] - np.mean(others)) < 4 * se for e in hit)
    warn = [o for t, o in got if t == "/status" and o.get("event") == "outliers"]
    assert len(warn) == len(hit) and "force_N at 40000" in warn[0]["message"]
