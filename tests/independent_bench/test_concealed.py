"""The independent bench's concealed suite (tests/independent_bench/concealed.py): its truth is in
the catalogue's names and outside the baseline, every hidden effect changes the recordings beyond
the noise of a 48-period record (measured here with numpy on the samples, nothing of hystbench's
analysis), the nulls hide nothing, and a case's day reads back with hystbench's reader.

Visibility, one point of the day at a time: the same point is simulated with and without the hidden
effect (same seed: the same noise draw), and the difference d is split, by the DFT of the record
(48 whole nominal periods), into its period-averaged part (the bins at multiples of 48) and the rest.
The period average's rms difference is compared with the noise's standard error on a period average,
sigma / sqrt(48), sigma the rms of the effect-free record about its own period average (white,
flicker and ADC together); an effect off the excitation's harmonics (mains) is compared line by line
with the local noise floor of the effect-free record's spectrum.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from hystbench.config.effects import CATALOGUE
from hystbench.formats.recording import read_recording
from independent_bench import BASELINE, simulate_recording
from independent_bench.bench import DEFAULTS, VARIANTS, effect_params
from independent_bench.bench import BenchConstants
from independent_bench.concealed import (ANOTHER_BENCH, ANOTHER_COPY, ANOTHER_SEED, CASES, DIAGNOSIS_BASELINE,
                                        KEPT_ON_THE_COPY, Case, day_points, drawn_copy, on_another_copy,
                                        without_hidden, write_case)

pytestmark = pytest.mark.slow(35)  # ~35 s: handed to a worker before lighter files (tests/conftest.py)

PERIODS = 48
FS_HZ = 100e3
#: A hidden effect must reach this many standard errors in some period average of its day ...
MIN_PERIODIC_SE = 5.0
#: ... or a line off the harmonics this many times the local noise floor (noise alone: ~4 at most).
MIN_LINE_FLOOR = 20.0
CHANNELS = ("current_A", "force_N", "flux_Wb")

EFFECT_CASES = [c for c in CASES if not c.null]
NULL_CASES = [c for c in CASES if c.null]


def test_the_suite_has_the_issues_shape():
    singles = [c for c in EFFECT_CASES if len(c.truth) == 1 and c.plan is None]
    assert {e for c in singles for e in c.truth} == {
        "magnet_eddy_currents", "iron_saturation", "frame_resonance", "charge_amp_highpass", "integrator_leak",
        "channel_skew", "force_offset_drift", "magnet_thermal_drift", "load_cell_compliance", "mains_pickup",
        "amplifier_distortion", "excess_loss", "magnetic_relaxation", "iron_thermal_drift"}
    assert 16 <= len(singles) <= 19
    assert len([c for c in EFFECT_CASES if len(c.truth) == 2]) >= 2
    assert any(c.plan is not None for c in EFFECT_CASES)
    assert len(NULL_CASES) >= 3 and any(c.bench is not None for c in NULL_CASES)
    assert len({c.seed for c in CASES}) == len(CASES)


@pytest.mark.parametrize("case", CASES, ids=lambda c: c.name)
def test_truth_is_catalogue_names_outside_the_baseline(case: Case):
    assert set(case.baseline) <= set(CATALOGUE)
    assert case.baseline == DIAGNOSIS_BASELINE == ("static_hysteresis", "lamination_eddy_currents",
                                                   "instrument_filter", "sensor_noise", "adc_quantisation")
    assert set(case.truth) <= set(CATALOGUE)
    assert not set(case.truth) & set(case.baseline)
    assert set(case.truth) == set(case.hidden) == set(case.expected)
    assert case.concealment


@pytest.mark.parametrize("case", NULL_CASES, ids=lambda c: c.name)
def test_a_null_hides_nothing(case: Case):
    assert case.truth == () and case.expected == {} and case.hidden == {}
    assert case.effects == BASELINE


def _spectra(cols: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    return {ch: np.fft.rfft(cols[ch]) for ch in CHANNELS if ch in cols}


def _visibility(on: dict[str, np.ndarray], off: dict[str, np.ndarray]) -> tuple[float, float]:
    """(period-averaged rms difference in noise SE, strongest off-harmonic line over the noise floor),
    the largest over the channels of one record."""
    periodic = line = 0.0
    off_s, on_s = _spectra(off), _spectra(on)
    for ch, x_off in off_s.items():
        n = off[ch].size
        d = on_s[ch] - x_off
        harm = np.zeros(x_off.size, bool)
        harm[::PERIODS] = True  # n is 48 whole periods: the period average lives on these bins
        weight = np.full(x_off.size, 2.0)
        weight[0] = 1.0
        sigma = np.sqrt(np.sum(weight[~harm] * np.abs(x_off[~harm]) ** 2) / n**2)
        rms_d = np.sqrt(np.sum(weight[harm] * np.abs(d[harm]) ** 2) / n**2)
        periodic = max(periodic, rms_d / (sigma / np.sqrt(PERIODS)))
        # lines: each off-harmonic bin of d against the median noise amplitude of its block of 48 bins
        m = (x_off.size - 1) // PERIODS * PERIODS
        noise = np.abs(np.where(harm, np.nan, x_off))[1:m + 1].reshape(-1, PERIODS)
        floor = np.repeat(np.nanmedian(noise, axis=1), PERIODS)
        dl = np.abs(np.where(harm, 0.0, d))[1:m + 1]
        line = max(line, float(np.max(dl / floor)))
    return periodic, line


def _points(case: Case) -> list[tuple[str, float, float, float]]:
    """The first and last frequency of each rig and current of the day, at their times on its clock
    (where every effect of the suite shows most: the low end's leads, the high end's modes and delays;
    a third of the day's cost)."""
    pts = list(day_points(case))
    keep = []
    for k, (rig, f, ipp, t) in enumerate(pts):
        block = [p for p in pts if p[0] == rig and p[2] == ipp]
        if f in (block[0][1], block[-1][1]):
            keep.append(pts[k])
    return keep


def _day_visibility(case: Case, hidden: dict) -> tuple[float, float]:
    periodic = line = 0.0
    base = without_hidden(case).effects
    for rig, f, ipp, t in _points(case):
        kw = dict(fs_hz=FS_HZ, periods=PERIODS, start_time_s=t, seed=case.seed, bench=case.bench)
        off, _ = simulate_recording(rig, f, ipp, effects=base, **kw)
        on, _ = simulate_recording(rig, f, ipp, effects={**base, **hidden}, **kw)
        p, q = _visibility(on, off)
        periodic, line = max(periodic, p), max(line, q)
    return periodic, line


@pytest.mark.parametrize("case, effect",
                         [pytest.param(c, e, id=f"{c.name}:{e}") for c in EFFECT_CASES for e in c.truth])
def test_every_hidden_effect_changes_the_recordings_beyond_the_noise(case: Case, effect: str):
    """Each hidden effect alone (a two-effect day: each of its two) over the same day without it."""
    periodic, line = _day_visibility(case, {effect: case.hidden[effect]})
    assert periodic >= MIN_PERIODIC_SE or line >= MIN_LINE_FLOOR, (periodic, line)


def test_the_visibility_measure_sees_noise_as_noise():
    """A difference that is the noise alone (a noisy record against the same without its noise and ADC)
    is ~1 SE in the period average and a few floors in any line: the thresholds are far above it."""
    case = NULL_CASES[0]
    quiet = {k: v for k, v in case.effects.items() if k not in ("sensor_noise", "adc_quantisation")}
    for rig, f, ipp, t in _points(case):
        noisy, _ = simulate_recording(rig, f, ipp, effects=case.effects, start_time_s=t, seed=case.seed)
        clean, _ = simulate_recording(rig, f, ipp, effects=quiet, start_time_s=t, seed=case.seed)
        periodic, line = _visibility(clean, noisy)
        assert periodic < 2.5 and line < MIN_LINE_FLOOR / 2, (rig, f, ipp, periodic, line)


def test_write_case_writes_a_day_hystbench_reads_back(tmp_path: Path):
    """One folder, the rigs of the case's plan (a partial day: a whole one takes 3 s to write)."""
    case = {c.name: c for c in CASES}["partial_ecores_current_skew"]
    folder = write_case(case, tmp_path / case.name)
    assert folder == tmp_path / case.name
    stems = sorted(p.with_suffix("") for p in folder.glob("*.csv"))
    assert len(stems) == len(case.points)
    recs = sorted((read_recording(s) for s in stems), key=lambda r: r.start_time_s)
    expected = list(day_points(case))
    assert [(r.rig, r.frequency_hz, r.current_pp_a) for r in recs] == [p[:3] for p in expected]
    assert [r.start_time_s for r in recs] == pytest.approx([p[3] for p in expected], abs=1e-9)
    assert {r.rig for r in recs} == {"ecore", "ecore_pm"}
    for r in recs:
        assert r.n == round(PERIODS * FS_HZ / r.frequency_hz)
        assert ("flux_Wb" in r.channels) == (r.rig != "voicecoil_ferrite")
        assert not {"effects", "seed", "truth"} & set(r.metadata)


def test_another_copy_moves_its_physics_and_keeps_what_each_case_chose():
    """The copy a diagnosis's settings are checked on (``python -m benchmarks diagnose --another-copy``):
    the same truth on other seeds; every parameter of every effect moved from the bench's default or
    declared kept (KEPT_ON_THE_COPY); each effect at the copy's parameters where the case left the
    default, the case's own choices kept (a mode at 2400 Hz, a null's clocks or geometry); ``expected``
    what is played."""
    for name, defaults in DEFAULTS.items():
        moved, kept = set(ANOTHER_COPY.get(name, {})), KEPT_ON_THE_COPY.get(name, frozenset())
        assert moved | kept == set(defaults) and not moved & kept, name
        for key in moved:
            ratio = abs(ANOTHER_COPY[name][key] / defaults[key])
            assert ratio != 1.0 and 1.0 / 2.5 <= ratio <= 2.5, (name, key, ratio)
    copies = {c.name: on_another_copy(c) for c in CASES}
    assert len({c.seed for c in copies.values()} | {c.seed for c in CASES}) == 2 * len(CASES)
    for case in CASES:
        copy = copies[case.name]
        assert (copy.truth, copy.plan, copy.baseline) == (case.truth, case.plan, case.baseline)
        assert copy.hidden.keys() == case.hidden.keys()
        params = effect_params(copy.effects)
        assert copy.expected == {e: params[e] for e in copy.truth}
        for name, p in params.items():
            own = case.effects[name] if isinstance(case.effects[name], dict) else {}
            for key, value in ANOTHER_COPY.get(name, {}).items():
                assert p[key] == own.get(key, value), (case.name, name, key)
        if case.bench is None:
            assert copy.bench == ANOTHER_BENCH
    assert copies["frame_resonance_2400"].effects["frame_resonance"]["frequency_Hz"] == 2400.0
    clocks, geometry = (next(c for c in CASES if c.name == n) for n in ("null_bench_clocks", "null_bench_geometry"))
    assert copies["null_bench_clocks"].bench == replace(
        ANOTHER_BENCH, adc_clock_ppm=clocks.bench.adc_clock_ppm, generator_clock_ppm=clocks.bench.generator_clock_ppm,
        amp_bandwidth_hz=clocks.bench.amp_bandwidth_hz, amp_gain_a_per_v=clocks.bench.amp_gain_a_per_v)
    assert copies["null_bench_geometry"].bench == replace(
        ANOTHER_BENCH, voice_coil_bl_n_per_a=geometry.bench.voice_coil_bl_n_per_a,
        ecore=replace(ANOTHER_BENCH.ecore, gap_m=geometry.bench.ecore.gap_m, depth_m=geometry.bench.ecore.depth_m))


def test_an_effect_of_another_family_has_no_copy_and_says_so():
    elliptic = replace(CASES[0], name="elliptic_day", effects={**CASES[0].effects,
                                                               "static_hysteresis": dict(VARIANTS["static_hysteresis"])})
    with pytest.raises(ValueError, match="elliptic_day.*static_hysteresis"):
        on_another_copy(elliptic)


def _fraction(nominal: float, value: float, copy: float) -> float:
    """How far ``value`` lies along the line from ``nominal`` to ``copy`` (1: at the copy; -1: as far the
    other way), in log for quantities of one sign, linearly for one that crosses zero."""
    if nominal * copy > 0:
        return float(np.log(value / nominal) / np.log(copy / nominal))
    return float((value - nominal) / (copy - nominal))


def test_a_drawn_copy_moves_what_the_copy_moves_as_far_or_less_either_way_one_fraction_per_effect():
    """``--drawn-copy SEED``: every parameter the hand-made copy moves lies between the default moved
    as far the other way and the copy's value, the parameters of one effect by one fraction (a loop
    stays of its family); what the copy keeps is kept; the mains on a grid; the same seed the same
    bench, two seeds two benches; a case's own choices still win, and its seeds are its own."""
    one, again, two = drawn_copy(1), drawn_copy(1), drawn_copy(2)
    assert one == again and one != two
    fractions = []
    for params, bench in (one, two):
        for name, moved in ANOTHER_COPY.items():
            if name == "mains_pickup":
                f = params[name]["frequency_Hz"]
                assert min(abs(f - 50.0), abs(f - 60.0)) <= 0.03
                continue
            u = {k: _fraction(DEFAULTS[name][k], params[name][k], v) for k, v in moved.items()}
            assert all(-1.0 <= x <= 1.0 for x in u.values()), (name, u)
            assert max(u.values()) - min(u.values()) < 1e-9, (name, u)  # one fraction per effect
            fractions.append(next(iter(u.values())))
            full = effect_params({name: params[name]})[name]
            assert {k for k in full if full[k] != DEFAULTS[name][k]} <= set(moved)
        nominal = BenchConstants()
        for obj, nom, copy in ((bench, nominal, ANOTHER_BENCH), (bench.ecore, nominal.ecore, ANOTHER_BENCH.ecore)):
            for key in vars(nom):
                if key == "ecore":
                    continue
                a, b, c = getattr(nom, key), getattr(obj, key), getattr(copy, key)
                if a == c:
                    assert b == a, key
                else:
                    assert -1.0 <= _fraction(a, b, c) <= 1.0, key
    assert min(fractions) < -0.2 and max(fractions) > 0.2  # both ways, not all at one end
    b1, b2 = one[1], two[1]
    moved_constants = ("adc_clock_ppm", "generator_clock_ppm", "amp_bandwidth_hz", "voice_coil_bl_n_per_a")
    u = [_fraction(getattr(BenchConstants(), k), getattr(b1, k), getattr(ANOTHER_BENCH, k)) for k in moved_constants]
    assert max(u) - min(u) > 0.1  # each constant its own fraction
    taken = {c.seed for c in CASES} | {c.seed + ANOTHER_SEED for c in CASES}
    for draw in (0, 1, 2):
        cases = [on_another_copy(c, draw) for c in CASES]
        seeds = {c.seed for c in cases}
        assert len(seeds) == len(CASES) and seeds.isdisjoint(taken), draw
        taken |= seeds
    cases = [on_another_copy(c, 1) for c in CASES]
    by_name = {c.name: c for c in cases}
    assert by_name["frame_resonance_2400"].effects["frame_resonance"]["frequency_Hz"] == 2400.0
    for case, copy in zip(CASES, cases):
        assert (copy.truth, copy.plan, copy.baseline) == (case.truth, case.plan, case.baseline)
        params = effect_params(copy.effects)
        assert copy.expected == {e: params[e] for e in copy.truth}
        for name in case.effects:  # the drawn copy's physics where the case left the default
            own = case.effects[name] if isinstance(case.effects[name], dict) else {}
            for key, value in one[0].get(name, {}).items():
                assert params[name][key] == own.get(key, value), (case.name, name, key)
        if case.bench is None:
            assert copy.bench == b1
    clocks = next(c for c in CASES if c.name == "null_bench_clocks")
    assert by_name["null_bench_clocks"].bench == replace(
        b1, adc_clock_ppm=clocks.bench.adc_clock_ppm, generator_clock_ppm=clocks.bench.generator_clock_ppm,
        amp_bandwidth_hz=clocks.bench.amp_bandwidth_hz, amp_gain_a_per_v=clocks.bench.amp_gain_a_per_v)
    assert b1 != b2
