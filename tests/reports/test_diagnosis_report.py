"""The diagnosis page and terminal table (hystbench/reports/diagnosis.py) on Diagnosis objects built
here: the verdict comes first, parameters read in the catalogue's names and units, the page is
written whole or not at all."""

from __future__ import annotations

import io

import numpy as np
import pytest
from rich.console import Console

from hystbench.analysis.diagnosis.result import Candidate, Diagnosis, Limit, Loops
from hystbench.reports.diagnosis import PAGE, plus_minus, print_summary, verdict, write_report


def _loops(channels=("current_A", "flux_Wb", "force_N")) -> Loops:
    ph = np.linspace(0.0, 1.0, 128, endpoint=False)
    s = {"current_A": 0.7 * np.sin(2 * np.pi * ph), "flux_Wb": 1e-4 * np.sin(2 * np.pi * ph - 0.05),
         "force_N": 170 + 40 * np.sin(2 * np.pi * ph - 0.06)}
    pick = {c: s[c] for c in channels}
    return Loops("ecore_pm_320Hz_1.4App", "ecore_pm", 320.0, 1.4, ph, pick, {k: 0.99 * v for k, v in pick.items()},
                 dict(pick))


def _diagnosis(named: bool = True, loops: Loops | None = None) -> Diagnosis:
    params = {"charge_amp_highpass": {"time_constant_s": (0.41, 0.02)}} if named else {}
    return Diagnosis(
        effect="charge_amp_highpass" if named else None, effects=["charge_amp_highpass"] if named else [],
        candidates=[Candidate("charge_amp_highpass", 80.0 if named else 3.0, {"time_constant_s": (0.41, 0.02)}),
                    Candidate("channel_skew", 12.0 if named else 1.0, {"force_N": (3.02e-6, 5e-8)})],
        parameters=params, recalibrated={"instrument.fn_hz": {"value": 4460.0, "std": 12.0, "prior": 4450.0}},
        located={"channels": {"force vs flux": 41.0}, "harmonics": {}, "frequencies_Hz": {}, "amplitudes_pp_A": {},
                 "rigs": {}, "time": {}},
        residual_before=40.0, residual_after=2.0 if named else 40.0, noise_floor={"force_N": 1e-3, "flux_Wb": 1e-9},
        seconds=3.0, baseline=["instrument_filter"], candidates_considered=["charge_amp_highpass", "channel_skew"],
        recordings=10, rigs=["ecore_pm"], loops=loops)


@pytest.mark.parametrize("value, std, text", [(0.41, 0.02, "0.41 +- 0.02"), (3.02e-6, 5e-8, "(3.02 +- 0.05)e-06"),
                                              (4460.0, 12.0, "4460 +- 12"), (2.0, None, "2")])
def test_a_value_is_quoted_to_its_standard_error(value, std, text):
    assert plus_minus(value, std) == text


def test_the_page_leads_with_the_verdict_and_names_parameters_with_units(tmp_path):
    d = _diagnosis(loops=_loops())
    page = write_report(d, tmp_path / "rep")
    assert page == tmp_path / "rep" / PAGE
    text = page.read_text()
    first = text.split("\n\n")[1]
    assert "charge_amp_highpass" in first and "40 to 2 noise floors (20x)" in first
    assert "charge_amp_highpass.time_constant_s = 0.41 +- 0.02 s" in text
    assert "channel_skew.force_N = (3.02 +- 0.05)e-06 s" in text
    assert "`instrument.fn_hz` | 4460 +- 12 Hz" in text
    assert (tmp_path / "rep" / "loops.png").read_bytes()[:4] == b"\x89PNG"


def test_nothing_named_says_so_and_invents_no_model(tmp_path):
    d = _diagnosis(named=False)
    assert verdict(d).startswith("No catalogue effect is named")
    text = write_report(d, tmp_path / "rep").read_text()
    assert "no invented physics" in text and "](loops.png)" not in text


def test_a_failure_half_way_leaves_nothing(tmp_path):
    d = _diagnosis(loops=_loops(channels=("force_N",)))  # no pair to draw: the figure fails after the page began
    with pytest.raises(ValueError):
        write_report(d, tmp_path / "rep")
    assert list(tmp_path.iterdir()) == []


def test_the_terminal_table_is_short_and_says_what_was_named():
    buf = io.StringIO()
    print_summary(_diagnosis(), Console(file=buf, width=120))
    out = buf.getvalue()
    assert "charge_amp_highpass.time_constant_s = 0.41 +- 0.02 s" in out and "(20x)" in out
    assert "channel_skew" in out and len(out.splitlines()) < 15


def test_the_terminal_table_gives_the_proof_in_the_signature_and_the_suspects():
    d = _diagnosis()
    d.signature = {"charge_amp_highpass": {"before": 30.0, "after": 1.5, "improvement": 20.0, "numbers": 42,
                                           "fold_gain": 12.0}}
    d.suspects = [Candidate("frame_resonance", 400.0, {}, held_out_gain=0.2),
                  Candidate("channel_skew", 90.0, {}, held_out_gain=1.7, held_out_total=0.004)]
    buf = io.StringIO()
    print_summary(d, Console(file=buf, width=160))
    out = buf.getvalue()
    assert "charge_amp_highpass: 30 -> 1.5 (20x; median fold 12x; 42 held-out numbers)" in out
    assert "frame_resonance (score 400, held out 0.2x, median fold)" in out
    assert "channel_skew (score 90, held out 1.7x, median fold; 0.004x in total)" in out


def test_a_none_says_what_the_day_could_have_named():
    """Nothing named: the page's table and the terminal give each candidate's limit, so that a "none" says
    which effects it speaks for; with a name, the terminal stays short and the page keeps the table."""
    limits = [Limit("channel_skew", "current_A", 7.3e-7, "s", False, True),
              Limit("charge_amp_highpass", "time_constant_s", 44.0, "s", True, True, "its DC replayed over 2 s"),
              Limit("load_cell_compliance", "stiffness_n_per_m", 0.0, "N/m", True, False)]
    d = _diagnosis(named=False)
    d.limits = limits
    buf = io.StringIO()
    print_summary(d, Console(file=buf, width=160))
    out = buf.getvalue()
    assert "named from" in out and "channel_skew current_A >= 7.3e-07 s" in out
    assert "load_cell_compliance stiffness_n_per_m none the catalogue's range reaches" in out
    named = _diagnosis()
    named.limits = limits
    buf = io.StringIO()
    print_summary(named, Console(file=buf, width=160))
    assert "named from" not in buf.getvalue()


def test_the_page_tables_what_the_day_can_decide(tmp_path):
    d = _diagnosis(named=False)
    d.limits = [Limit("magnet_thermal_drift", "kelvin_per_s", 0.079, "K/s", False, True, either_sign=True),
                Limit("charge_amp_highpass", "time_constant_s", 44.0, "s", True, True, "its DC replayed over 2 s")]
    text = write_report(d, tmp_path / "rep").read_text()
    assert "### What this day can decide" in text
    assert "| `magnet_thermal_drift` | kelvin_per_s | >= 0.079 K/s either way |" in text
    assert "| `charge_amp_highpass` | time_constant_s | <= 44 s (its DC replayed over 2 s) |" in text
