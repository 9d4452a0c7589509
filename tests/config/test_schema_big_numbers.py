"""An integer too large for a float (TOML's reader and JSON's read integers of any length) is refused
as out of range by the one validator, naming file, table and key; before, ``float()`` raised an
OverflowError past the CLI (``hystbench simulate --rig big.toml`` ended in a traceback)."""

from __future__ import annotations

import tomllib

import pytest

from hystbench.config.schema import NUM, Key, check_table
from hystbench.errors import ConfigError

HUGE = 10**400  # float(HUGE) overflows: the largest float is about 1.8e308

SCHEMA = {"rate_hz": Key(NUM, 100.0, "a rate", "Hz", gt=0, le=1e6), "gain": Key(NUM, 1.0, "any finite gain"),
          "bits": Key(NUM, 16, "whole", ge=2, le=32, whole=True)}


@pytest.mark.parametrize("key, value, words", [
    ("rate_hz", HUGE, "rate_hz: must be in (0, 1e+06]"),
    ("rate_hz", -HUGE, "rate_hz: must be in (0, 1e+06]"),
    ("gain", HUGE, "gain: must be a finite number"),
    ("bits", HUGE, "bits: must be a whole number in [2, 32]"),
])
def test_an_integer_beyond_the_floats_is_out_of_range(key, value, words) -> None:
    with pytest.raises(ConfigError) as info:
        check_table({key: value}, "f.toml", SCHEMA, "t")
    assert str(info.value).startswith(f"f.toml [t] {words}")


def test_as_read_from_a_toml_file() -> None:
    data = tomllib.loads("rate_hz = 1" + "0" * 400)
    assert data["rate_hz"] == HUGE  # what the reader gives: no bound on integers
    with pytest.raises(ConfigError, match=r"f\.toml \[t\] rate_hz: must be in \(0, 1e\+06\]"):
        check_table(data, "f.toml", SCHEMA, "t")
