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
