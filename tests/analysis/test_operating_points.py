"""``hystbench rigs --json``: each preset's operating point, written in the recording sidecar's
spelling by the one translation (formats.recording.with_point) and read back by its inverse."""

from __future__ import annotations

import tomllib

from hystbench.analysis.operating_points import operating_points
from hystbench.config import CONFIG_DIR
from hystbench.formats.recording import sidecar_point
from hystbench.messages import OperatingPoint


def test_each_row_is_its_presets_excitation_in_the_sidecar_spelling() -> None:
    rows = {r["rig"]: r for r in operating_points()}
    files = {p.stem: p for p in (CONFIG_DIR / "rigs").glob("*.toml")}
    assert set(rows) == set(files)
    for name, row in rows.items():
        exc = tomllib.loads(files[name].read_text(encoding="utf-8"))["excitation"]  # the file, read directly
        assert row["frequency_Hz"] == exc["frequency_hz"] and row["current_pp_A"] == exc["current_pp_a"]
        assert "offset_A" not in row  # a preset states no offset: the row says none
        p = sidecar_point(row)
        assert (p.frequency_hz, p.current_pp_a) == (exc["frequency_hz"], exc["current_pp_a"])
        assert p == OperatingPoint(exc["frequency_hz"], exc["current_pp_a"])  # offset 0, output on


def test_a_segment_at_another_frequency_carries_the_generators_clock_error_to_it() -> None:
    """``record --freq 1000`` on the bench source: the log's recording metadata is the start's (320 Hz,
    the emulated generator at 320.008 Hz); the exported 1000 Hz segment said generator_frequency_Hz
    320.008 beside frequency_Hz 1000.  The generator's clock error (25 ppm here) is its own at any
    frequency: 1000.025 Hz."""
    from hystbench.formats.recording import with_point

    base = {"frequency_Hz": 320.0, "generator_frequency_Hz": 320.008, "current_pp_A": 1.4}
    meta = with_point(base, OperatingPoint(1000.0, 1.4, 0.0))
    assert meta["frequency_Hz"] == 1000.0 and abs(meta["generator_frequency_Hz"] - 1000.025) < 1e-9
    assert with_point(base, OperatingPoint(320.0, 1.4, 0.0))["generator_frequency_Hz"] == 320.008  # untouched
