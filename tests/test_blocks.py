"""The sample block's typed operating point: read once from its meta (the wire form), None where the
meta names none, carried through concatenation."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from hystbench.blocks import SampleBlock, concatenate
from hystbench.messages import OperatingPoint

finite = st.floats(allow_nan=False, allow_infinity=False)
points = st.builds(OperatingPoint, finite, finite, finite, st.booleans(), st.booleans(), st.integers(0, 2**53))


def block(first: int = 0, n: int = 4, meta: dict | None = None) -> SampleBlock:
    return SampleBlock(first, 1000.0, {"current_A": np.arange(n, dtype=float)}, meta=meta if meta is not None else {})


@settings(max_examples=100, deadline=None)
@given(points)
def test_a_block_s_point_is_the_one_its_meta_was_written_from(p: OperatingPoint) -> None:
    b = block(meta={**p.to_meta(), "skew_s.force_N": 3e-6})  # a driver's note beside it changes nothing
    assert isinstance(b.point, OperatingPoint) and b.point == p
    assert b.point is b.point  # read once, then kept


def test_a_block_whose_meta_names_no_point_has_none() -> None:
    assert block().point is None
    assert block(meta={"skew_s.force_N": 3e-6}).point is None
    partial = block(meta={"table": 2.0}).point  # one key names a point: the rest are from_meta's defaults
    assert partial.table == 2 and math.isnan(partial.frequency_hz) and partial.output_on


def test_concatenation_keeps_the_first_block_s_point() -> None:
    p = OperatingPoint(320.0, 1.4, settling=True, table=3)
    joined = concatenate([block(0, meta=p.to_meta()), block(4, meta=p.to_meta())])
    assert joined.n == 8 and joined.point == p
