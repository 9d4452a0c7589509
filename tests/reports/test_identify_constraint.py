"""Issue 30, item 7: ``identify`` says so when a fitted corner frequency lies above the sweep (or is
uncertain by a large part of itself): the number is the fit's extrapolation, not a measurement."""

from __future__ import annotations

import json
from types import SimpleNamespace

import numpy as np
import pytest

from hystbench.cli.main import main
from hystbench.formats.recording import write_sweep
from hystbench.reports.identify import _poorly_constrained
from hystbench.sim_backend.recordings import simulate_voice_coil_sweep


@pytest.fixture(scope="module")
def sweep_to_8khz(tmp_path_factory):
    """The ferrite coil (load cell resonance 4.45 kHz, second corner about 31 kHz) swept to 8 kHz."""
    out = tmp_path_factory.mktemp("coil") / "vc"
    write_sweep(simulate_voice_coil_sweep("voicecoil_ferrite", np.round(np.geomspace(200.0, 8000.0, 10), 2)), out)
    return out


def test_a_corner_above_the_sweep_is_called_poorly_constrained(sweep_to_8khz, capsys):
    assert main(["identify", str(sweep_to_8khz), "--json"]) == 0
    rep = json.loads(capsys.readouterr().out)
    assert rep["frequency_range_Hz"][1] == pytest.approx(8000.0, rel=1e-3)  # as measured
    assert rep["parameters"]["f0_Hz"] > 8000.0  # the premise: the fit put it beyond the sweep
    assert set(rep["poorly_constrained"]) == {"f0_Hz"}  # the resonance inside the sweep is measured
    assert "above the sweep (max 8000 Hz)" in rep["poorly_constrained"]["f0_Hz"]
    assert main(["identify", str(sweep_to_8khz)]) == 0
    text = " ".join(capsys.readouterr().out.split())  # the table's console may wrap the line
    assert "f0_Hz" in text and "above the sweep (max 8000 Hz): poorly constrained" in text


def _fit(fn, fn_std, f0, f0_std, f_max):
    return SimpleNamespace(params={"fn_Hz": fn, "f0_Hz": f0}, std={"fn_Hz": fn_std, "f0_Hz": f0_std},
                           response=SimpleNamespace(frequency_hz=np.array([10.0, f_max])))


def test_corners_inside_the_sweep_and_well_measured_are_not_flagged():
    assert _poorly_constrained(_fit(4450.0, 5.0, 31000.0, 900.0, 45000.0)) == {}


def test_a_corner_inside_the_sweep_with_a_large_uncertainty_is_flagged():
    poor = _poorly_constrained(_fit(4450.0, 5.0, 31000.0, 12000.0, 45000.0))
    assert set(poor) == {"f0_Hz"} and "poorly constrained" in poor["f0_Hz"] and "39 %" in poor["f0_Hz"]
