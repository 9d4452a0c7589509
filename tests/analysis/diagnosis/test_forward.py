"""The replay (analysis/diagnosis/forward.py) is the simulation a diagnosis compares with: it must be the
bench day itself, noise aside.  A bench day is simulated by sim_backend.bench_day (its own code path:
one rig per type, settling, recording whole records) and replayed from the recordings' sidecars alone;
their features must agree to the noise-free level, slow effects and transients included."""

from __future__ import annotations

import numpy as np
import pytest

from hystbench.analysis.diagnosis import forward
from hystbench.analysis.diagnosis.forward import replayed_features as _replayed_features
from hystbench.analysis.diagnosis.columns import catalogue_params
from hystbench.analysis.diagnosis.features import record_features
from hystbench.analysis.diagnosis.forward import points_of, record_mean, replay, with_effects
from hystbench.analysis.diagnosis.select import DC_BLIND
from hystbench.config import load_rig
from hystbench.sim_backend.bench_day import BenchDayPlan, bench_effects, simulate_bench_day
from hystbench.sim_backend.rig import DEFAULT_FS_HZ

QUIET = {"sensor_noise": False, "adc_quantisation": False}


def _presets_with(effects: dict[str, dict]) -> dict[str, dict]:
    """Each rig's preset with its own effects (noise off) and ``effects`` on top, as the generator had."""
    out = {}
    for rig, extra in effects.items():
        p = load_rig(rig)
        eff = {n: catalogue_params(p, n) for n in p["effects"] if n not in QUIET}
        eff.update({n: {**catalogue_params(p, n), **v} for n, v in extra.items() if v is not False})
        out[rig] = with_effects(p, eff)
    return out


@pytest.mark.parametrize("extra", [
    {},
    {"charge_amp_highpass": {"time_constant_s": 2.0}},  # transients after every change of operating point
    {"force_offset_drift": {"offset_n": 0.1, "drift_n_per_s": 0.05}},  # the day's clock across rigs
], ids=["presets", "highpass", "drift"])
def test_the_replay_is_the_bench_day(extra):
    per_rig = bench_effects({**extra, **QUIET})
    recs = simulate_bench_day(BenchDayPlan.quick(), seed=3, effects=per_rig)
    features = [record_features(r) for r in recs]
    points, clocked = points_of(recs, [f.periods / f.frequency_hz for f in features])
    assert clocked
    truth_effects = {rig: {k: v for k, v in e.items() if k not in QUIET} for rig, e in per_rig.items()}
    reps = replay(_presets_with(truth_effects), points)
    for rec, data, rep in zip(recs, features, reps):
        model = _replayed_features(rep)
        for ch in ("current_A", "flux_Wb", "force_N"):
            if ch not in data.harmonics:
                continue
            d, m = data.harmonics[ch], model.harmonics[ch]
            scale = np.nanmax(np.abs(d[1:]))
            ok = np.isfinite(d) & np.isfinite(m)
            # AC: the same samples but for the window; DC: a record's mean from three windows
            assert np.max(np.abs(d[ok][1:] - m[ok][1:])) < 2e-5 * scale, (rec.rig, rec.frequency_hz, ch)
            tol = 2e-3 if extra.get("charge_amp_highpass") else 2e-5
            assert abs(d[0] - m[0]) < tol * max(scale, abs(d[0])), (rec.rig, rec.frequency_hz, ch, d[0], m[0])


def test_record_mean_integrates_a_quadratic_exactly():
    a, b, c = 0.3, -1.2, 2.0
    span = (1.0, 4.0)
    centres = [1.2, 2.5, 3.8]
    values = [a * (t - 1.0) ** 2 + b * (t - 1.0) + c for t in centres]
    exact = (a * 27 / 3 + b * 9 / 2 + c * 3) / 3  # mean of the quadratic over 3 s
    assert record_mean(values, centres, span) == pytest.approx(exact, rel=1e-12)


#: The force's noise floor of a period average on our bench day and the independent bench's (5.1e-4 and
#: 5.9e-4 N, their diagnosis reports): what a difference of the replay is judged against.
FORCE_FLOOR_N = 5e-4


def _highpass_force_harmonics(monkeypatch, tau_s: float, cap_s: float) -> np.ndarray:
    """The force harmonics 1-7 of an ``ecore_pm`` replay with a high-pass of ``tau_s``, its memory capped
    at ``cap_s``: four points 100 s apart, as the independent bench's day has them, so that a cap bites."""
    preset = load_rig("ecore_pm")
    effects = {n: catalogue_params(preset, n) for n in preset["effects"] if n not in QUIET}
    preset = with_effects(preset, {**effects, "charge_amp_highpass": {"time_constant_s": tau_s}})
    points = [forward.Point(f"p{i}", "ecore_pm", f, ipp, 5.0 + 100.0 * i, 0.3, DEFAULT_FS_HZ)
              for i, (f, ipp) in enumerate([(40.0, 0.7), (160.0, 1.4), (40.0, 1.4), (160.0, 0.7)])]
    monkeypatch.setattr(forward, "MEMORY_CAP_S", cap_s)
    return np.array([f.harmonics["force_N"][1:8] for f in forward.replay_features(preset, points)])


@pytest.mark.parametrize("tau_s", [1.0, 4.0])
def test_a_high_pass_is_followed_long_enough_for_the_force_harmonics(monkeypatch, tau_s):
    """The replay follows a high-pass's memory for at most MEMORY_CAP_S, not its 5 tau: the force's DC is
    not compared with one (select.DC_BLIND), and its harmonics must be those of a replay that follows
    the whole memory, to a tenth of the noise floor."""
    assert "charge_amp_highpass" in DC_BLIND  # the premise: its DC is never compared
    cap_s = forward.MEMORY_CAP_S
    assert 5.0 * tau_s > cap_s  # the cap bites
    capped = _highpass_force_harmonics(monkeypatch, tau_s, cap_s)
    whole = _highpass_force_harmonics(monkeypatch, tau_s, 5.0 * tau_s)
    assert np.max(np.abs(capped - whole)) < 0.1 * FORCE_FLOOR_N


def test_with_no_memory_a_short_high_pass_leaks_into_the_force_harmonics(monkeypatch):
    """The control: the memory matters.  A 0.25 s high-pass replayed from a standing start at each point
    (only the settling) is still steep in the window, and its curvature moves the force's harmonics by
    more than a noise floor."""
    whole = _highpass_force_harmonics(monkeypatch, 0.25, 1.25)
    assert np.max(np.abs(_highpass_force_harmonics(monkeypatch, 0.25, 0.0) - whole)) > FORCE_FLOOR_N


def _rec(rig: str, f: float, ipp: float, start: float, flux: bool = True):
    from hystbench.formats.recording import Recording

    channels = {"current_A": np.zeros(8), **({"flux_Wb": np.zeros(8)} if flux else {})}
    return Recording(None, 100e3, channels, {"rig": rig, "frequency_Hz": f, "current_pp_A": ipp,
                                             "sample_rate_Hz": 100e3, "start_time_s": start})


def test_a_day_played_in_frequency_order_is_told_its_clock_runs_with_the_frequency():
    """The bench-day plan (each block's frequencies up, one clock): the clock and frequency are one
    direction in every block that records flux.  One block shuffled breaks it; the voice coil's ordered
    sweep (no flux, no iron discrepancy), a block of two points and one frequency repeated do not count."""
    freqs = (40.0, 80.0, 160.0, 320.0, 480.0)
    day = [_rec("voicecoil_ferrite", f, 1.0, t, flux=False) for t, f in enumerate((40.0, 400.0, 3000.0))]
    day += [_rec("ecore", f, 1.27, 100 + 10 * i) for i, f in enumerate(freqs)]
    day += [_rec("ecore_pm", f, 0.7, 200 + 10 * i) for i, f in enumerate(freqs[::-1])]  # down counts too
    day += [_rec("ecore_pm", f, 1.4, 300 + 10 * i) for i, f in enumerate((40.0, 480.0))]
    assert forward.clock_follows_frequency(day)
    shuffled = day[:3] + [_rec("ecore", f, 1.27, 100 + 10 * i) for i, f in enumerate((40.0, 480.0, 160.0, 80.0, 320.0))]
    assert not forward.clock_follows_frequency(shuffled + day[8:])
    assert not forward.clock_follows_frequency(day[:3])  # no block with flux: nothing to say
    repeated = [_rec("ecore", 320.0, 1.27, 10 * i) for i in range(4)]  # one frequency again and again
    assert not forward.clock_follows_frequency(repeated)


def test_a_replay_the_simulator_cannot_make_names_its_recording(monkeypatch):
    """A voice coil's recording whose sidecar said ``ecore`` ended the diagnosis with "ecore (ecore):
    the iron's field did not converge at 200 Hz ...", naming no file: the recording is named first."""
    from hystbench.analysis.diagnosis import forward
    from hystbench.config import load_rig
    from hystbench.errors import SimulationError

    def fails(self, n):
        raise SimulationError("ecore (ecore): the iron's field did not converge")

    monkeypatch.setattr(forward.SimulatedRig, "read", fails)
    point = forward.Point("day/ecore/vc_200Hz_1App", "ecore", 200.0, 1.0, 0.0, 0.1, 100_000.0)
    with pytest.raises(SimulationError, match=r"^day/ecore/vc_200Hz_1App: its replay on the simulated ecore at 200 Hz, "
                                              r"1 A-pp failed \(is the sidecar's rig the one recorded\?\): ecore \(ecore\)"):
        forward.replay_rig(load_rig("ecore"), [point])
