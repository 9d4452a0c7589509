"""The rig's command sine and the measurement chain as numba kernels (issue 14): each kernel against
the reference it replaces, computed independently (scipy.signal.sosfilt, np.sin, numpy's clip and
round), across random cuts of the stream; then the whole rig on both paths, ADC code for ADC code."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import signal

from hystbench import jit
from hystbench.blocks import BlockFlags
from hystbench.sim_backend import measurement, rig as rig_module
from hystbench.sim_backend.actuators import ecore
from hystbench.sim_backend.measurement import _NOISE_KEYS, noise_adc_reference
from hystbench.sim_backend.rig import SimulatedRig

pytestmark = pytest.mark.skipif(not jit.enabled(), reason="numba not installed (or HYSTBENCH_JIT=0)")

QUIET = {"sensor_noise": False, "adc_quantisation": False}


def kernels():
    from hystbench.sim_backend import kernels as k

    return k


def cuts(n: int, seed: int, parts: int) -> list[int]:
    """Random cut points in (0, n), sorted, with the ends: blocks of 1 sample included."""
    rng = np.random.default_rng(seed)
    inner = np.unique(rng.integers(1, n, size=parts)) if n > 1 else np.array([], dtype=int)
    return [0, *inner.tolist(), n]


@pytest.fixture
def path(monkeypatch):
    """Run every part of the rig on one path: ``path(False)`` numpy, ``path(True)`` kernels."""
    def set_path(on: bool) -> None:
        for module in (measurement, rig_module, ecore):
            monkeypatch.setattr(module, "KERNEL", on)
    return set_path


# --- the force filter: scipy's sosfilt, the state carried across cuts ---------------------------------
@settings(max_examples=40, deadline=None)
@given(order=st.integers(1, 7), seed=st.integers(0, 2**32 - 1), parts=st.integers(0, 12))
def test_sos_kernel_is_scipys_sosfilt_across_any_cut(order, seed, parts):
    rng = np.random.default_rng(seed)
    sos = signal.butter(order, rng.uniform(0.01, 0.45), output="sos")  # odd orders: a single section at the end
    if rng.random() < 0.5:
        sos = np.vstack([sos, signal.cheby1(2, 1.0, rng.uniform(0.02, 0.4), btype="high", output="sos")])
    n = int(rng.integers(1, 3000))
    x = rng.standard_normal(n) * 10.0 ** rng.uniform(-6, 3)
    zi0 = signal.sosfilt_zi(sos) * x[0]
    expected, zf = signal.sosfilt(sos, x, zi=zi0)  # uncut, scipy
    zi = np.ascontiguousarray(zi0)
    got = np.empty(n)
    edges = cuts(n, seed, parts)
    for a, b in zip(edges[:-1], edges[1:]):
        if (a + b) % 2:  # into a new array, or in place
            kernels().sosfilt(np.ascontiguousarray(sos), zi, x[a:b], got[a:b])
        else:
            y = x[a:b].copy()
            kernels().sosfilt(np.ascontiguousarray(sos), zi, y, y)
            got[a:b] = y
    scale = max(np.max(np.abs(expected)), 1e-300)
    assert np.max(np.abs(got - expected)) <= 1e-12 * scale
    np.testing.assert_allclose(zi, zf, rtol=0, atol=1e-12 * max(np.max(np.abs(zf)), 1e-300))


def test_the_chain_force_filter_gives_the_same_samples_on_both_paths(monkeypatch):
    """``_Sos`` itself: the kernel path and the scipy path, fed the same blocks, one state each."""
    rig = SimulatedRig("ecore_pm", effects=QUIET)
    sos = rig.chain._force_filter.sos
    x = np.random.default_rng(5).standard_normal(5000)
    edges = cuts(5000, 2, 9)
    out = {}
    for on in (False, True):
        monkeypatch.setattr(measurement, "KERNEL", on)
        f = measurement._Sos(sos)
        out[on] = np.concatenate([f(x[a:b]) for a, b in zip(edges[:-1], edges[1:])])
    expected, _ = signal.sosfilt(sos, x, zi=signal.sosfilt_zi(sos) * x[0])
    np.testing.assert_allclose(out[False], expected, rtol=0, atol=1e-12 * np.max(np.abs(expected)))
    np.testing.assert_allclose(out[True], expected, rtol=0, atol=1e-12 * np.max(np.abs(expected)))


# --- the command sine: angle addition against np.sin of the phase -------------------------------------
@settings(max_examples=40, deadline=None)
@given(c0=st.floats(0.0, 1.0, exclude_max=True), step=st.floats(1e-7, 0.5, exclude_max=True),
       n=st.integers(1, 5000), seed=st.integers(0, 2**32 - 1), parts=st.integers(0, 10))
def test_sine_kernel_is_npsin_of_the_phase_across_any_cut(c0, step, n, seed, parts):
    """One block: against np.sin(2 pi (c0 + step k)) with the same c0; cut as the rig cuts it (the
    phase carried mod 1), against the uncut phase: within 1e-12 of the amplitude either way, plus
    the rounding of the phase itself (a few ulp of 2 pi (c0 + step n) rad), which np.sin's argument
    carries too (a rig's block is at most 1 + step n cycles: 2e-14 rad at 320 Hz, 10k samples)."""
    tol = 1e-12 + 1e-15 * 2 * np.pi * (c0 + step * n)
    amp, w, offset = 1.0, 2 * np.pi * 320.0, 0.0
    k = np.arange(n)
    i_ref, di_ref = np.sin(2 * np.pi * (c0 + step * k)), w * np.cos(2 * np.pi * (c0 + step * k))
    i_got, di_got = np.empty(n), np.empty(n)
    kernels().sine_and_rate(c0, step, offset, amp, amp * w, i_got, di_got)
    assert np.max(np.abs(i_got - i_ref)) <= tol
    assert np.max(np.abs(di_got - di_ref)) <= tol * w
    phase = c0
    for a, b in zip(cuts(n, seed, parts)[:-1], cuts(n, seed, parts)[1:]):
        kernels().sine_and_rate(phase, step, offset, amp, amp * w, i_got[a:b], di_got[a:b])
        phase = float(np.mod(phase + step * (b - a), 1.0))
    assert np.max(np.abs(i_got - i_ref)) <= tol
    assert np.max(np.abs(di_got - di_ref)) <= tol * w


def test_the_rig_command_is_the_same_on_both_paths(monkeypatch):
    rig = SimulatedRig("ecore_pm", effects=QUIET, current_pp_a=1.4, offset_a=0.3)
    step = rig.generator_frequency_hz / rig.fs_hz
    out = {}
    for on in (False, True):
        monkeypatch.setattr(rig_module, "KERNEL", on)
        out[on] = rig._command_current(0.731, step, 7777)
    for ref, got in zip(out[False], out[True]):
        np.testing.assert_allclose(got, ref, rtol=0, atol=1e-12 * np.max(np.abs(ref)))
    assert not np.array_equal(out[True][0], np.zeros(7777))


# --- noise and the ADC: the same codes and the same CLIP flag --------------------------------------------
@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(1, 3000), noisy=st.booleans(), quantise=st.booleans(),
       bits=st.sampled_from([8, 12, 16, 24]), reach=st.floats(0.1, 3.0))
def test_noise_adc_kernel_gives_the_reference_codes_and_clip_flag(seed, n, noisy, quantise, bits, reach):
    rng = np.random.default_rng(seed)
    full_scale = 10.0 ** rng.uniform(-9, 3)
    x = reach * full_scale * np.sin(np.linspace(0, 7, n)) + full_scale * 1e-3 * rng.standard_normal(n)
    lsb = 2.0 * full_scale / 2**bits
    x[rng.integers(0, n, size=min(n, 20))] = lsb * (rng.integers(-50, 50, size=min(n, 20)) + 0.5)  # ties
    draws = rng.standard_normal(n)
    sigma = full_scale * 1e-2
    ref, ref_clip = noise_adc_reference(x, sigma if noisy else None, draws if noisy else None,
                                        full_scale if quantise else None, lsb)
    out = np.empty(n)
    clip = kernels().noise_adc(x, sigma, draws, noisy, full_scale, lsb, quantise, out)
    assert np.array_equal(out, ref)
    assert clip == ref_clip == (quantise and bool(np.any(np.abs(x + (sigma * draws if noisy else 0)) > full_scale)))


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), sizes=st.lists(st.integers(0, 3000), min_size=1, max_size=4))
def test_noise_draws_kernel_gives_numpys_draws_and_leaves_the_same_state(seed, sizes):
    """numba's Generator must run numpy's ziggurat on the shared bit generator: the same draws,
    and the generator where numpy would have left it (the next block's draws depend on it)."""
    from hystbench.sim_backend import kernels

    ours, theirs = np.random.default_rng(seed), np.random.default_rng(seed)
    for n in sizes:
        out = np.empty(n)
        kernels.standard_normal(ours, out)
        np.testing.assert_array_equal(out, theirs.standard_normal(n))
    assert ours.bit_generator.state == theirs.bit_generator.state


def test_noise_adc_reference_is_todays_expression():
    """The numpy reference is the chain's expression: x + sigma*noise, clip to one LSB below full
    scale, round half to even on the LSB grid (checked here with Python's own round)."""
    full_scale, lsb = 0.5, 2 * 0.5 / 2**16
    x = np.array([0.0, 0.49999, 0.7, -0.7, 2.5 * lsb, 3.5 * lsb, -2.5 * lsb])
    y, clipped = noise_adc_reference(x, None, None, full_scale, lsb)
    assert clipped
    assert y.tolist() == [round(min(max(v, -full_scale), full_scale - lsb) / lsb) * lsb for v in x.tolist()]
    assert y[2] == full_scale - lsb and y[3] == -full_scale and y[4] == 2 * lsb and y[5] == 4 * lsb


@pytest.mark.parametrize("on", [False, True], ids=["numpy", "kernel"])
def test_quantisation_rounds_to_the_lsb_and_flags_clipping_on_both_paths(path, on):
    """test_rig's quantisation test on each path: 0.7 A peak on a 0.5 A range flags CLIP."""
    path(on)
    rig = SimulatedRig("ecore_pm", effects={"static_hysteresis": False, "iron_saturation": False,
                                            "sensor_noise": False, "adc_quantisation": {"current_a": 0.5}})
    block = rig.read(2000)
    lsb = 2 * 0.5 / 2**16
    i = block.channels["current_A"]
    assert np.array_equal(i / lsb, np.round(i / lsb))
    assert i.max() == 0.5 - lsb and i.min() == -0.5 and BlockFlags.CLIP in block.flags
    quiet = SimulatedRig("ecore_pm", effects={"sensor_noise": False}).read(2000)
    assert BlockFlags.CLIP not in quiet.flags


# --- the whole rig ----------------------------------------------------------------------------------------
def record(path, on: bool, name: str, seed: int, blocks: list[int], **kwargs):
    path(on)
    r = SimulatedRig(name, seed=seed, **kwargs)
    parts = [r.read(b) for b in blocks]
    return r, {ch: np.concatenate([p.channels[ch] for p in parts]) for ch in parts[0].channels}, \
        [p.flags for p in parts]


@pytest.mark.parametrize("name,seed,frequency", [("ecore_pm", 1, None), ("ecore_pm", 5, 480.0),
                                                 ("ecore", 2, 40.0), ("voicecoil_ndfeb", 3, None)])
def test_whole_rig_gives_the_same_adc_codes_on_both_paths(path, name, seed, frequency):
    """Every effect of the preset on (noise and ADC too): the same code in every sample of every channel."""
    blocks = [7000, 1, 333, 10_000, 2666]
    r, ref, ref_flags = record(path, False, name, seed, blocks, frequency_hz=frequency)
    _, got, got_flags = record(path, True, name, seed, blocks, frequency_hz=frequency)
    q = r.effects["adc_quantisation"]
    for ch in ref:
        lsb = 2.0 * float(q[_NOISE_KEYS[ch]]) / 2 ** int(q["bits"])
        codes = np.round(ref[ch] / lsb)
        assert np.array_equal(codes * lsb, ref[ch])  # they are ADC codes
        assert np.array_equal(got[ch], ref[ch]), ch
        assert np.unique(codes).size > 50, ch  # a live channel, not a constant
    assert got_flags == ref_flags


@pytest.mark.parametrize("name", ["ecore_pm", "voicecoil_ndfeb"])
def test_whole_rig_quiet_agrees_to_rounding_on_both_paths(path, name):
    """No noise, no ADC: the sine and the filter differ by a few ulp at most, never by physics."""
    blocks = [5000, 17, 4983]
    _, ref, _ = record(path, False, name, 4, blocks, effects=QUIET)
    _, got, _ = record(path, True, name, 4, blocks, effects=QUIET)
    for ch in ref:
        span = np.ptp(ref[ch])
        assert span > 0
        assert np.max(np.abs(got[ch] - ref[ch])) <= 1e-9 * span, ch


@pytest.mark.parametrize("on", [False, True], ids=["numpy", "kernel"])
def test_both_paths_give_the_adc_codes_recorded_before_issue_14(path, on, golden_instrument, changed_since_golden):
    """The golden recording (tests/sim_backend/data/ecore_golden.npz, made on commit 3b1f019 by
    make_ecore_golden.py, before any kernel): ecore_pm with its preset's effects, the load cell
    sampled as then (``golden_instrument``), every code to the closure of the iron's branches since
    (test_ecore_kernel.CLOSURE_CODES, CLOSURE_SAME), but the channels changed on purpose since
    (``changed_since_golden``); both paths give the same codes exactly (above)."""
    from pathlib import Path

    golden = np.load(Path(__file__).with_name("data") / "ecore_golden.npz")
    _, got, _ = record(path, on, "ecore_pm", 1, [1000] * 4)
    for ch, x in got.items():
        if ch in changed_since_golden:
            changed_since_golden[ch](x, golden[f"pm_adc/{ch}"], golden[f"pm_adc/{ch}/lsb"])
            continue
        codes = np.round(x / golden[f"pm_adc/{ch}/lsb"])
        assert np.max(np.abs(codes - golden[f"pm_adc/{ch}"])) <= 2, ch
        assert np.mean(codes == golden[f"pm_adc/{ch}"]) >= 0.95, ch
