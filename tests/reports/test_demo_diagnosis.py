"""``make demo`` ends with a diagnosis of a concealed bench day written by the independent bench
(issues 13 and 27): it names the effect that bench hid, with the time constant of the circuit that
bench simulates, and writes the report; the truth file beside the day is printed after the verdict.
``hystbench demo`` checks ``--day``, ``--baseline`` and ``--truth`` before anything runs."""

from __future__ import annotations

import io
import json
import re

import pytest
from rich.console import Console

from hystbench.cli.main import main
from hystbench.reports.demo_diagnosis import demo_diagnosis
from independent_bench.__main__ import main as write_independent_day
from independent_bench.concealed import CASES

pytestmark = pytest.mark.slow(40)  # ~40 s: handed to a worker before lighter files (tests/conftest.py)

#: make demo's integrator_leak day, on the E-core with magnet alone (10 of its 24 recordings): the same
#: diagnosis in half the time; make demo and the benchmark diagnose the whole day
DAY = "partial_ecore_pm_integrator_leak"
BASELINE = ["static_hysteresis", "lamination_eddy_currents", "instrument_filter", "sensor_noise", "adc_quantisation"]


@pytest.fixture(scope="module")
def independent_day(tmp_path_factory):
    out = tmp_path_factory.mktemp("independent")
    assert write_independent_day([DAY, str(out)]) == 0
    return out


def test_the_writer_keeps_the_truth_beside_the_day_never_in_it(independent_day):
    truth = json.loads((independent_day / "truth.json").read_text())
    assert truth["truth"] == ["integrator_leak"] and truth["baseline"] == BASELINE
    # the circuit's leak: 4.7 MOhm || the op-amp's 20000 x 10 kOhm, on 100 nF
    assert truth["catalogue"]["integrator_leak"]["time_constant_s"] == pytest.approx(1 / (1 / 0.47 + 1 / 20.0), rel=1e-3)
    sidecars = [p.read_text() for p in (independent_day / "day").glob("*.json")]
    plan = next(c for c in CASES if c.name == DAY).points  # the independent bench's own plan of that day
    assert len(sidecars) == len(plan) == 10 and not any("leak" in s or "truth" in s for s in sidecars)


def test_the_demo_names_what_the_independent_bench_hid_and_writes_its_report(independent_day, tmp_path):
    buf = io.StringIO()
    page = demo_diagnosis(tmp_path / "diagnosis", Console(file=buf, width=200), day=independent_day / "day",
                          baseline=BASELINE, truth=independent_day / "truth.json")
    out = buf.getvalue()
    assert page == tmp_path / "diagnosis" / "report" / "README.md"
    assert "**integrator_leak**" in page.read_text().split("\n\n")[1]  # the verdict names the bench's truth
    assert (page.parent / "loops.png").exists() and (page.parent / "heat_map.png").exists()
    line = next(x for x in out.splitlines() if "integrator_leak.time_constant_s = " in x)
    tau = float(line.split("= ")[1].split()[0])
    assert tau == pytest.approx(1 / (1 / 0.47 + 1 / 20.0), rel=0.05)  # the circuit's, not our simulator's
    assert "truth (never shown to the diagnosis): integrator_leak" in out and "--baseline " + ",".join(BASELINE) in out
    # what a candidate does that the calibration cannot: a compliance at the magnet's bias force is a
    # smaller airgap (first order), so almost none of it is its own, and the knobs do nearly all of it;
    # the leak's lead, 1/f on the flux alone, is far more its own
    own = {m[1]: (float(m[2]), m[3]) for m in re.finditer(r"\| 1 \| `(\w+)`[^|]*\| [^|]+ \| ([0-9.e+-]+) its own, [0-9.]+ % within ([^|]+?) \|", page.read_text())}
    assert own["load_cell_compliance"][0] < 1e-4 and own["load_cell_compliance"][1] == "the calibration's knobs"
    assert own["integrator_leak"][0] > 1e3 * own["load_cell_compliance"][0]
    # the bench played each of ecore_pm's two blocks up in frequency: the report says what that hides
    assert "frequencies were played in order" in page.read_text()


@pytest.mark.parametrize("argv, says", [
    (["--truth", "t.json"], "--truth: only with --day"),
    (["--baseline", "static_hysteresis"], "--baseline: only with --day"),
    (["--day", "{tmp}/nowhere"], "nowhere"),
    (["--day", "{day}", "--truth", "{day}/../day"], "--truth"),
])
def test_the_demo_refuses_a_bad_day_before_it_starts(argv, says, independent_day, tmp_path, capsys):
    argv = [a.format(tmp=tmp_path, day=independent_day / "day") for a in argv]
    assert main(["demo", "--out", str(tmp_path / "out"), *argv]) == 2
    assert says in capsys.readouterr().err
    assert not (tmp_path / "out").exists()  # nothing ran
