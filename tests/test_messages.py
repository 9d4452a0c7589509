"""The live path's message types: symmetric JSON (property-tested, in memory and through the bytes
the writers put on the wire), the operating point in block meta, and malformed messages refused
naming the key."""

from __future__ import annotations

import json
import math
from dataclasses import fields, replace

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hystbench.errors import RecordingError
from hystbench.messages import OPERATING_KEYS, Estimate, OperatingPoint, json_bytes

finite = st.floats(allow_nan=False, allow_infinity=False)
names = st.sampled_from(["hysteresis", "instrument", "total"])
channels = st.sampled_from(["current_A", "force_N", "flux_Wb"])

points = st.builds(OperatingPoint, finite, finite, finite, st.booleans(), st.booleans(), st.integers(0, 2**53))
estimates = st.builds(
    Estimate, st.integers(-2**62, 2**62), st.integers(-2**62, 2**62), st.integers(0, 2**63 - 1), finite, finite,
    table=st.integers(0, 2**53), error=st.none() | st.text(), frequency_hz=finite, frequency_std_hz=finite,
    harmonic=st.integers(0, 4), delays_s=st.dictionaries(names, finite), delays_std_s=st.dictionaries(names, finite),
    phases_deg=st.dictionaries(names, finite), phases_std_deg=st.dictionaries(names, finite),
    outliers=st.dictionaries(channels, st.lists(st.integers(0, 2**62), max_size=5).map(tuple)),
    outliers_excluded=st.booleans())


@settings(max_examples=200, deadline=None)
@given(estimates)
def test_an_estimate_reads_back_what_it_wrote(e: Estimate) -> None:
    assert Estimate.from_json(e.to_json()) == e
    assert Estimate.from_json(json.loads(json_bytes(e.to_json()))) == e  # through the wire's bytes


@settings(max_examples=200, deadline=None)
@given(points)
def test_an_operating_point_reads_back_what_it_wrote_as_json_and_as_block_meta(p: OperatingPoint) -> None:
    assert OperatingPoint.from_json(p.to_json()) == p
    assert OperatingPoint.from_json(json.loads(json_bytes(p.to_json()))) == p
    meta = p.to_meta()
    assert all(isinstance(v, float) for v in meta.values())  # block meta: numbers only
    assert set(meta) == set(OPERATING_KEYS) - ({"settling"} if not p.settling else set())
    assert OperatingPoint.from_meta(meta) == p


def test_the_meta_keys_are_the_fields_and_missing_ones_come_from_the_nominal_point() -> None:
    assert OPERATING_KEYS == tuple(f.name for f in fields(OperatingPoint))
    nominal = OperatingPoint(320.0, 1.4, offset_a=0.2)
    assert OperatingPoint.from_meta({}, nominal) == nominal
    assert OperatingPoint.from_meta({"frequency_hz": 80.0, "output_on": 0.0}, nominal) == \
        replace(nominal, frequency_hz=80.0, output_on=False)
    bare = OperatingPoint.from_meta({"table": 2.0})  # no nominal: the point is not known, the output taken as on
    assert math.isnan(bare.frequency_hz) and math.isnan(bare.current_pp_a) and bare.table == 2 and bare.excited


def test_the_peak_current_is_the_offset_plus_half_the_peak_to_peak() -> None:
    """What a bench's current limit bounds: a sine of I_pp around the offset peaks at |offset| + I_pp/2
    on either side of zero."""
    assert OperatingPoint(320.0, 1.4, offset_a=0.2).peak_a == pytest.approx(0.9)
    assert OperatingPoint(320.0, 1.0, offset_a=-0.5).peak_a == pytest.approx(1.0)  # the negative lobe


def test_nan_is_written_as_null_and_read_back_as_nan() -> None:
    e = Estimate(0, 100, 5, 320.0, 1.4, delays_s={"hysteresis": math.nan})
    wire = json.loads(json_bytes(e.to_json()))
    assert wire["frequency_hz"] is None and wire["delays_s"] == {"hysteresis": None}
    back = Estimate.from_json(wire)
    assert math.isnan(back.frequency_hz) and math.isnan(back.delays_s["hysteresis"])


def test_one_json_bytes_for_the_log_and_the_bus() -> None:
    """The MCAP recorder and zenoh write small messages with the one json_bytes of the vocabulary
    (issue 11): the schemas module of the log no longer holds it, and both writers use the same
    function object."""
    import numpy as np

    from hystbench.acquisition import zenoh_bus
    from hystbench.formats.mcaplog import recorder, schemas

    assert not hasattr(schemas, "json_bytes")
    assert recorder.json_bytes is json_bytes and zenoh_bus.json_bytes is json_bytes
    assert json.loads(json_bytes({"x": np.float32(0.5), "y": (math.inf, 2)})) == {"x": 0.5, "y": [None, 2]}


@pytest.mark.parametrize("obj, key", [
    ({"end_index": 1, "t_ns": 0, "nominal_frequency_hz": 1.0, "current_pp_a": 1.0}, "missing key 'first_index'"),
    ({"first_index": "0", "end_index": 1, "t_ns": 0, "nominal_frequency_hz": 1.0, "current_pp_a": 1.0},
     "key 'first_index' must be an integer"),
    ({"first_index": 0, "end_index": 1, "t_ns": 0, "nominal_frequency_hz": 1.0, "current_pp_a": 1.0,
      "delays_s": {"total": "slow"}}, "key 'delays_s'\\['total'\\] must be a number"),
    ({"first_index": 0, "end_index": 1, "t_ns": 0, "nominal_frequency_Hz": 1.0, "current_pp_A": 1.0},
     "missing key 'nominal_frequency_hz'"),  # the sidecar's spelling is not the live path's
    ([1, 2], "must be a JSON object"),
])
def test_a_malformed_estimate_is_refused_naming_the_key(obj, key) -> None:
    with pytest.raises(RecordingError, match=f"estimate message: {key}"):
        Estimate.from_json(obj)


def test_the_schema_is_the_fields() -> None:
    schema = Estimate.json_schema()
    assert list(schema["properties"]) == [f.name for f in fields(Estimate)]
    assert schema["required"] == ["first_index", "end_index", "t_ns", "nominal_frequency_hz", "current_pp_a"]
    assert schema["properties"]["outliers"] == {
        "type": "object", "additionalProperties": {"type": "array", "items": {"type": "integer"}},
        "description": schema["properties"]["outliers"]["description"]}
    assert schema["properties"]["error"]["type"] == ["string", "null"]
    assert OperatingPoint.json_schema()["properties"]["output_on"]["type"] == "boolean"
