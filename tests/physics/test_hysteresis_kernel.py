"""The compiled kernels of the Preisach iron (``physics/hysteresis_kernel.py``) against the numpy code
they replaced, which stays as the reference (``HYSTBENCH_JIT=0``): the branch table gives the same H at
every target of every branch, on the shipped Preisach materials and on irons a fit passes through
(distributions narrow and wide, centred low and high), at the fitting tables' size and the
simulator's; the field gives the same H and end state along any trajectory."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from hystbench.compensator.hysteresis_eddy import FIT_TABLES, material_dict, preisach_params
from hystbench.config import load_material
from hystbench.jit import enabled
from hystbench.physics import hysteresis
from hystbench.physics.hysteresis import PreisachHysteresis
from hystbench.physics.hysteresis_kernel import field_along

pytestmark = pytest.mark.skipif(not enabled(), reason="numba missing or HYSTBENCH_JIT=0: no kernel to check")


def _tables(params, monkeypatch, jit: bool) -> dict:
    with monkeypatch.context() as m:
        m.setattr(hysteresis, "jit_enabled", lambda: jit)
        return PreisachHysteresis(params)._build_inverse()


def _same(params, monkeypatch) -> None:
    ref, got = _tables(params, monkeypatch, False), _tables(params, monkeypatch, True)
    assert got.keys() == ref.keys()
    np.testing.assert_allclose(got["psi"], ref["psi"], rtol=1e-13, atol=0.0)  # sinh's ulps, if the libm differs
    for k in ("virgin", "anhyst"):
        np.testing.assert_array_equal(got[k][1], ref[k][1])


@pytest.mark.parametrize("name", ["M330-50A", "M130-27S"])
@pytest.mark.parametrize("size", ["shipped", "fit"])
def test_the_shipped_irons_give_numpys_table(name, size, monkeypatch):
    params = PreisachHysteresis.from_config(load_material(name)).params
    _same(params if size == "shipped" else dataclasses.replace(params, **FIT_TABLES), monkeypatch)


@settings(max_examples=25, deadline=None)
@given(j_irr=st.floats(0.1, 2.0), centre=st.floats(10.0, 400.0), width=st.floats(0.05, 2.0),
       lorentz=st.floats(1e-3, 10.0), j1=st.floats(1e-3, 1.0), h1=st.floats(1.0, 1e4))
def test_any_fitted_iron_gives_numpys_table(j_irr, centre, width, lorentz, j1, h1):
    material = material_dict(j_irr, [("gauss", 1.0, centre, width * centre), ("lorentz", lorentz, 1.4 * centre,
                                                                              2 * width * centre)],
                             [(j1, 8.0 * centre), (1.0, 1.0e4)], centre / 3.0)
    with pytest.MonkeyPatch.context() as mp:
        _same(preisach_params(material, FIT_TABLES), mp)


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), material=st.sampled_from(["M330-50A", "M130-27S"]),
       irreversible=st.booleans(), saturation=st.booleans(), peak=st.floats(0.05, 1.6))
def test_field_along_is_the_numpy_field_from_any_state(seed, material, irreversible, saturation, peak):
    """The compiled field (field_along: the fits' and the waveform diagnosis's) and
    PreisachHysteresis.field give the same H and the same end state along a trajectory of nested
    minor loops, from the demagnetised state and then on from where the first one ended."""
    iron = _PREISACH.setdefault(material, PreisachHysteresis.from_config(load_material(material)))
    rng = np.random.default_rng(seed)
    t = np.arange(1500) / 1500
    tones = [rng.uniform(0.1, 1.0) * peak * np.sin(2 * np.pi * rng.uniform(1, 40) * t + rng.uniform(0, 6.3))
             for _ in range(3)]
    b = np.clip(np.sum(tones, axis=0) / 2 + 0.01 * peak * rng.standard_normal(t.size), -1.6, 1.6)
    state = iron.initial_state()
    for part in (b[:900], b[900:]):
        h_ref, ref = iron.field(part, state, irreversible=irreversible, saturation=saturation)
        h, end = field_along(iron, part, state, irreversible=irreversible, saturation=saturation)
        np.testing.assert_allclose(h, h_ref, rtol=0, atol=1e-12 * max(np.ptp(h_ref), 1.0))
        assert end.direction == ref.direction and len(end.turns) == len(ref.turns)
        # the turning points hold B (T) beside H (A/m, up to thousands): each to 1e-12 of its own size (an
        # H of -752.76 A/m once differed by 7 ulps, 1.25e-12, between the two paths' roundings)
        np.testing.assert_allclose(np.ravel(end.turns), np.ravel(ref.turns), rtol=1e-12, atol=1e-12)
        state = ref


_PREISACH: dict = {}  # a material's tables built once per worker (the hypothesis examples share them)
