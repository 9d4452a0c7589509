"""The compiled branch table of the Preisach iron (``physics/hysteresis_kernel.py``) against the numpy
code it replaced, which stays as the reference (``HYSTBENCH_JIT=0``): the same H at every target of
every branch, on the shipped Preisach materials and on irons a fit passes through (distributions
narrow and wide, centred low and high), at the fitting tables' size and the simulator's."""

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
