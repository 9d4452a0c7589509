"""The one validator (check_table) and the one TOML reader (read_toml) every file goes through."""

from __future__ import annotations

from pathlib import Path

import pytest

from hystbench.config import read_toml
from hystbench.config.schema import NUM, OPTIONAL, Key, check_table, tables
from hystbench.errors import ConfigError

SCHEMA = {
    "rate_hz": Key(NUM, 100.0, "a rate", "Hz", gt=0),
    "count": Key(int, None, "required", ge=1, le=10),
    "mode": Key(str, "a", "a choice", choices=("a", "b")),
    "fraction": Key(NUM, OPTIONAL, "left out: absent", ge=0, lt=1),
    "bits": Key(NUM, 16, "whole", ge=2, le=32, whole=True),
    "freqs": Key(list, [1.0], "a list", "Hz", items=Key(NUM, None, "frequencies", "Hz", gt=0), nonempty=True),
    "sub": Key(dict, {}, "a sub-table", table={"gain": Key(NUM, 0.5, "a gain", ge=0)}),
    "rows": Key(list, [], "an array of tables", items=Key(dict, None, "rows", table={"w": Key(NUM, None, "w", gt=0)})),
}


def check(data: dict) -> dict:
    return check_table(data, "f.toml", SCHEMA, "t")


def refused(data: dict) -> str:
    with pytest.raises(ConfigError) as info:
        check(data)
    return str(info.value)


def test_defaults_are_filled_numbers_are_floats_and_optional_keys_stay_out() -> None:
    out = check({"count": 3, "rate_hz": 50, "bits": 12.0, "rows": [{"w": 2}]})
    assert out == {"rate_hz": 50.0, "count": 3, "mode": "a", "bits": 12, "freqs": [1.0], "sub": {"gain": 0.5},
                   "rows": [{"w": 2.0}]}
    assert type(out["rate_hz"]) is float and type(out["bits"]) is int and "fraction" not in out
    assert check({"count": 1, "fraction": 0})["fraction"] == 0.0


@pytest.mark.parametrize("data, expected", [
    ({"count": 3, "rate": 5}, "f.toml [t]: unknown key 'rate'; known: rate_hz, count, mode, fraction"),
    ({"count": 3, "extra": {}}, "f.toml [t]: unknown section [t.extra]"),
    ({}, "f.toml [t]: missing key 'count'"),
    ({"count": 0}, "f.toml [t] count: must be in [1, 10], got 0"),
    ({"count": 2.0}, "f.toml [t] count: must be int in [1, 10], got 2.0"),
    ({"count": True}, "f.toml [t] count: must be int"),  # a bool is not a number in TOML
    ({"count": 1, "rate_hz": 0}, "f.toml [t] rate_hz: must be > 0, got 0"),
    ({"count": 1, "rate_hz": "fast"}, "f.toml [t] rate_hz: must be a number > 0, got 'fast'"),
    ({"count": 1, "rate_hz": float("inf")}, "f.toml [t] rate_hz: must be > 0, got inf"),
    ({"count": 1, "fraction": 1.0}, "f.toml [t] fraction: must be in [0, 1), got 1.0"),
    ({"count": 1, "mode": "c"}, "f.toml [t] mode: must be one of a, b, got 'c'"),
    ({"count": 1, "bits": 12.5}, "f.toml [t] bits: must be a whole number in [2, 32], got 12.5"),
    ({"count": 1, "freqs": []}, "f.toml [t] freqs: must be a non-empty list of frequencies > 0 Hz, got []"),
    ({"count": 1, "freqs": [5, -1]}, "f.toml [t] freqs: must be a non-empty list of frequencies > 0 Hz"),
    ({"count": 1, "sub": {"gain": -1}}, "f.toml [t.sub] gain: must be >= 0, got -1"),
    ({"count": 1, "sub": 3}, "f.toml [t.sub]: must be a table, got 3"),
    ({"count": 1, "rows": [{"w": 1}, {"w": 0}]}, "f.toml [t.rows[1]] w: must be > 0, got 0"),
])
def test_every_refusal_names_file_table_and_key(data: dict, expected: str) -> None:
    assert refused(data).startswith(expected)


def test_nothing_of_the_input_is_shared_with_the_result() -> None:
    data = {"count": 1, "freqs": [2.0]}
    out = check(data)
    out["freqs"].append(3.0)
    out["sub"]["gain"] = 9.0
    assert data == {"count": 1, "freqs": [2.0]} and check({"count": 1})["sub"] == {"gain": 0.5}


def test_tables_walks_the_schema_in_file_order() -> None:
    assert [(p, list(k), a) for p, k, a in tables(SCHEMA)] == [
        ("", ["rate_hz", "count", "mode", "fraction", "bits", "freqs"], False), ("sub", ["gain"], False),
        ("rows", ["w"], True)]


def test_read_toml_names_the_file_for_every_way_it_can_fail(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match=r"nope.toml: no such daemon file"):
        read_toml(tmp_path / "nope.toml", "daemon file")
    bad = tmp_path / "bad.toml"
    bad.write_text("[a\n", encoding="utf-8")
    with pytest.raises(ConfigError, match=r"bad.toml: not valid TOML"):
        read_toml(bad)
    latin = tmp_path / "latin.toml"
    latin.write_bytes(b'name = "\xe9"\n')  # not UTF-8, which TOML requires
    with pytest.raises(ConfigError, match=r"latin.toml: cannot read the file"):
        read_toml(latin)
    with pytest.raises(ConfigError, match=r"cannot read the file"):
        read_toml(tmp_path)  # a folder


def test_every_number_has_a_size_bound_beside_its_own_range():
    """A rig's remanence of 1e300 T passed 'must be > 0' and overflowed the force map (a traceback)."""
    from hystbench.config.schema import MAX_MAGNITUDE

    key = Key(NUM, None, "remanent flux density", "T", gt=0.0)
    assert key.problem(MAX_MAGNITUDE) is None and key.problem(1.5) is None
    assert key.problem(1e300) == "must be > 0 and at most 1e+15 in size"
    assert Key(NUM, None, "an offset").problem(-1e300) == "must be at most 1e+15 in size"


def test_a_file_saved_with_a_byte_order_mark_reads_as_its_text(tmp_path):
    """An editor's "UTF-8 with BOM" made every config file "not valid TOML: Invalid statement (at line 1,
    column 1)"; the mark is not part of what the file says."""
    (tmp_path / "bom.toml").write_bytes(b"\xef\xbb\xbf" + b'[daemon]\nbench = "b"\n')
    assert read_toml(tmp_path / "bom.toml") == {"daemon": {"bench": "b"}}
    (tmp_path / "latin.toml").write_bytes(b'name = "\xe9"\n')  # not UTF-8: still refused, naming the file
    with pytest.raises(ConfigError, match=r"latin\.toml: cannot read the file"):
        read_toml(tmp_path / "latin.toml")
