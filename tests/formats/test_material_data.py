"""The material-table reader: the vendored real data read back unchanged, and every defect named
with its file, line and column."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from hystbench.errors import BenchError, RecordingError
from hystbench.formats.material_data import REQUIRED_SIDECAR_KEYS, read_material_table

REAL = Path(__file__).resolve().parents[1] / "data" / "real"


def test_vendored_tables_read_with_their_sources():
    n87 = read_material_table(REAL / "magnet_N87_sine.csv")
    assert n87.kind == "core_loss" and n87.material == "N87" and len(n87) == 964
    assert n87.metadata["licence"]["name"] == "MIT" and (REAL / n87.metadata["licence"]["file"]).is_file()
    # first data line of the file, parsed here independently of the reader
    first = (REAL / "magnet_N87_sine.csv").read_text().splitlines()[1].split(",")
    assert [n87.frequency_hz[0], n87.flux_density_t[0], n87.columns["loss_W_per_m3"][0]] == [float(x) for x in first]
    mu = read_material_table(REAL / "N87_mu_large.csv")
    assert mu.kind == "complex_permeability" and len(mu) == 4572
    assert np.all(mu.columns["mu_imag"] < 0) and (REAL / mu.metadata["licence"]["file"]).is_file()
    for name in ("magnet_3C90_sine", "magnet_3E6_sine", "magnet_N49_sine"):
        t = read_material_table(REAL / f"{name}.csv")
        assert t.metadata["temperature_C"] == 25.0 and np.all(t.columns["loss_W_per_m3"] > 0)


@pytest.fixture
def table(tmp_path: Path) -> Path:
    for suffix in (".csv", ".json"):
        shutil.copy(REAL / f"magnet_N87_sine{suffix}", tmp_path / f"t{suffix}")
    return tmp_path / "t.csv"


def _edit_line(path: Path, lineno: int, text: str) -> None:
    lines = path.read_text().splitlines()
    lines[lineno - 1] = text
    path.write_text("\n".join(lines) + "\n")


@pytest.mark.parametrize("line, message", [
    ("50000.0,nan,180.18", ":5: column 2 (flux_density_peak_T): 'nan' is not a finite number"),
    ("50000.0,0.01,inf", ":5: column 3 (loss_W_per_m3): 'inf' is not a finite number"),
    ("50000.0,0.01,-3.5", ":5: column 3 (loss_W_per_m3): -3.5 must be >= 0"),
    ("50000.0,0.01,", ":5: column 3 (loss_W_per_m3): empty field"),
    ("50000.0,0.01", ":5: 2 fields, the header has 3"),
    ("0,0.01,5", ":5: column 1 (frequency_Hz): 0.0 must be > 0"),
    ("50000.0,0.01,1_0", ":5: column 3 (loss_W_per_m3): '1_0' is not a finite number"),
])
def test_bad_value_named_by_line_and_column(table: Path, line: str, message: str):
    _edit_line(table, 5, line)
    with pytest.raises(RecordingError) as err:
        read_material_table(table)
    assert str(err.value) == f"{table}{message}" or str(err.value).startswith(f"{table}{message}")


def test_wrong_header_is_named(table: Path):
    _edit_line(table, 1, "frequency_Hz,flux_density_T,loss_W_per_m3")
    with pytest.raises(RecordingError, match=r"t\.csv:1: header .* is not the core_loss layout"):
        read_material_table(table)


@pytest.mark.parametrize("key", REQUIRED_SIDECAR_KEYS)
def test_missing_sidecar_key_is_named(table: Path, key: str):
    side = table.with_suffix(".json")
    meta = json.loads(side.read_text())
    del meta[key]
    side.write_text(json.dumps(meta))
    with pytest.raises(BenchError, match=rf"t\.json: missing key '{key}'"):
        read_material_table(table)


def test_missing_sidecar_and_bad_json(table: Path):
    side = table.with_suffix(".json")
    side.write_text('{"material": "N87",\n "kind": }')
    with pytest.raises(RecordingError, match=r"t\.json:2: column \d+: not valid JSON"):
        read_material_table(table)
    side.unlink()
    with pytest.raises(RecordingError, match=r"t\.json: missing sidecar"):
        read_material_table(table)


def test_units_must_cover_the_columns(table: Path):
    side = table.with_suffix(".json")
    meta = json.loads(side.read_text())
    meta["units"].pop("loss_W_per_m3")
    side.write_text(json.dumps(meta))
    with pytest.raises(RecordingError, match=r"key 'units' must give the unit of every column"):
        read_material_table(table)


def test_permeability_sign_is_checked(tmp_path: Path):
    for suffix in (".csv", ".json"):
        shutil.copy(REAL / f"N87_mu_large{suffix}", tmp_path / f"m{suffix}")
    _edit_line(tmp_path / "m.csv", 3, "50000.0,0.07,3400.0,12.5")
    with pytest.raises(RecordingError, match=r"m\.csv:3: column 4 \(mu_imag\): 12.5 must be <= 0"):
        read_material_table(tmp_path / "m.csv")
