"""The static law's inverse and reachable range, and force references (parsing, refusals)."""

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from hystbench.compensator import ForceReference, StaticLaw, UnreachableReference
from hystbench.errors import BenchError, ConfigError

PM = StaticLaw(175.0, 66.0, 5.0, magnet=True)
NO = StaticLaw(0.0, 0.0, 8.26, magnet=False)


@settings(max_examples=200, deadline=None)
@given(j=st.floats(-1.5, 1.5))
def test_magnet_law_inverts_its_force(j):
    assert PM.invert(PM.force(j)) == pytest.approx(j, abs=1e-9)


@settings(max_examples=200, deadline=None)
@given(j=st.floats(0.0, 1.5))
def test_quadratic_law_inverts_to_the_positive_root(j):
    assert NO.invert(NO.force(j)) == pytest.approx(j, abs=1e-7)


def test_reachable_ranges():
    lo, hi = NO.reachable_n(1.0)
    assert lo == 0.0 and hi == pytest.approx(8.26)
    lo, hi = PM.reachable_n(1.0)
    assert (lo, hi) == pytest.approx((175 - 66 + 5, 175 + 66 + 5))


def test_negative_force_without_magnet_is_refused_with_the_range():
    with pytest.raises(UnreachableReference, match="only attracts.*reachable 0 to 26.7") as err:
        NO.invert(np.array([1.0, -0.5]), current_limit_a=1.8)
    assert err.value.reachable_n == pytest.approx((0.0, 8.26 * 1.8**2))
    assert isinstance(err.value, BenchError)


def test_force_beyond_the_current_limit_is_refused_with_the_range():
    with pytest.raises(UnreachableReference, match=r"needs 1.918 A static current, above the 1.8 A limit; reachable 72.4 to 310 N"):
        PM.invert(np.array([170.0, 320.0]), current_limit_a=1.8)
    with pytest.raises(UnreachableReference, match="below the magnet's force at zero gap flux"):
        PM.invert(np.array([-100.0]))


def test_parse_sine_and_multisine():
    ref = ForceReference.parse("offset=170,amp=40,freq=320")
    assert ref.frequency_hz == 320 and ref.n == 1000
    assert ref.range_n == pytest.approx((130.0, 210.0), abs=1e-6)
    assert ref.force_n[250] == pytest.approx(210.0)  # amp sin(2 pi t f): the peak a quarter period in
    ms = ForceReference.parse("offset=10, amp=2, freq=100, phase=90, h3=1@-90")
    ph = np.arange(1000) / 1000
    expect = 10 + 2 * np.cos(2 * np.pi * ph) - np.cos(2 * np.pi * 3 * ph)
    assert ms.force_n == pytest.approx(expect, abs=1e-9)
    assert "300 Hz" in ms.description


@pytest.mark.parametrize("spec, match", [
    ("offset=1,amp=1", "missing freq="),
    ("offset=1,amp=1,freq=10,gain=3", "unknown key 'gain'"),
    ("offset=1,amp=x,freq=10", "amp='x' is not a number"),
    ("offset=1,amp=nan,freq=10", "not finite"),
    ("offset=1,amp=0,freq=10", "no AC part"),
    ("offset=1,amp=-1,freq=10", "amplitudes must be >= 0"),
    ("offset=1,amp=1,freq=-10", "positive number of Hz"),
    ("offset=1,amp 1,freq=3", "not KEY=VALUE"),
    ("offset=1,amp=1,freq=10,freq=20", "given twice"),
])
def test_bad_references_are_refused_naming_the_key(spec, match):
    with pytest.raises(ConfigError, match=match):
        ForceReference.parse(spec)


def test_reference_from_csv(tmp_path):
    path = tmp_path / "ref.csv"
    path.write_text("force_N,other\n" + "\n".join(f"{2 + np.sin(2 * np.pi * k / 64)},0" for k in range(64)) + "\n")
    ref = ForceReference.from_csv(path, 80.0)
    assert ref.n == 64 and ref.frequency_hz == 80.0
    path.write_bytes(b"\xef\xbb\xbf" + path.read_bytes())  # as Excel saves UTF-8: "no column 'force_N'" before
    np.testing.assert_array_equal(ForceReference.from_csv(path, 80.0).force_n, ref.force_n)
    path.write_text("force_N\n1\nnan\n" + "2\n" * 20)
    with pytest.raises(ConfigError, match=r"ref.csv:3: column 'force_N' is not a finite number"):
        ForceReference.from_csv(path, 80.0)
    with pytest.raises(ConfigError, match="no column 'F'"):
        ForceReference.from_csv(path, 80.0, column="F")
