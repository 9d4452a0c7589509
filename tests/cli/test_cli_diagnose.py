"""``hystbench diagnose`` (issue 13): bad input is one line naming the file or option, exit 2, nothing
written; a voice-coil-only day is diagnosed with a warning about what cannot be located; ``--json``
is the stable document with the issue's keys; ``--report`` is a page with its figures."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from hystbench.cli.main import main
from hystbench.formats.recording import write_sweep
from hystbench.sim_backend.bench_day import BenchDayPlan, RigBlock, simulate_bench_day
from hystbench.sim_backend.recordings import simulate_recording

pytestmark = pytest.mark.slow(30)  # ~30 s: handed to a worker before lighter files (tests/conftest.py)

#: The stable keys of ``--json`` (the issue's list).
ISSUE_KEYS = {"effect", "effects", "candidates", "parameters", "recalibrated", "located", "residual_before",
              "residual_after", "improvement", "noise_floor", "seconds"}
LOCATED_KEYS = {"channels", "harmonics", "frequencies_Hz", "amplitudes_pp_A", "rigs", "time"}


def _write_day(root: Path, plan: BenchDayPlan, seed: int = 5) -> list[Path]:
    recs = simulate_bench_day(plan, seed=seed)
    folders = []
    for rig in plan.rigs:
        folders.append(root / rig)
        write_sweep([r for r in recs if r.rig == rig], folders[-1])
    return folders


def _no_stage_left(root: Path) -> bool:
    return not [p for p in root.rglob(".*") if p.name.endswith(".tmp")]


@pytest.fixture(scope="module")
def day(tmp_path_factory) -> list[Path]:
    """A short bench day of the three rigs, one sweep folder per rig."""
    return _write_day(tmp_path_factory.mktemp("day"), BenchDayPlan.quick())


@pytest.fixture()
def ecore_one(tmp_path) -> Path:
    """A sweep folder holding one recording."""
    write_sweep([simulate_recording("ecore", 80.0, 1.27, 0.05, seed=1)], tmp_path / "one")
    return tmp_path / "one"


def _run(args: list[str], capsys) -> tuple[int, str, str]:
    code = main(["diagnose", *args])
    out, err = capsys.readouterr()
    return code, out, err


def test_a_folder_given_twice_is_refused_before_the_work(day, capsys):
    """The same folder twice, or a day and one of its rigs, would count recordings twice (a clean day
    then showed a force drift): refused, naming both."""
    root = day[0].parent
    for args in ([str(root), str(root)], [str(root), str(day[1])]):
        code, out, err = _run(args, capsys)
        assert code == 2 and out == "" and err.count("\n") == 1
        assert f"{args[1]}: given twice" in err and str(root) in err


def test_a_recordings_csv_given_alone_is_told_to_be_given_as_its_folder(ecore_one, capsys):
    csv = next(ecore_one.glob("*.csv"))
    code, out, err = _run([str(csv)], capsys)
    assert code == 2 and out == "" and err.count("\n") == 1
    assert f"{csv}: a recording (its first column is time_s), not a loss table" in err and f"({ecore_one})" in err


def test_a_sweep_with_one_recording_is_refused(ecore_one, capsys):
    code, out, err = _run([str(ecore_one)], capsys)
    assert code == 2 and out == ""
    assert err.count("\n") == 1 and str(ecore_one) in err and "several operating points" in err
    assert "80 Hz" in err


def test_a_log_with_one_operating_point_is_refused_naming_the_log(tmp_path, capsys):
    log = tmp_path / "one.mcap"
    assert main(["record", "--source", "sim", "--rig", "ecore", "--freq", "320", "--ipp", "1", "--seconds", "0.05",
                 "--pace", "max", "--out", str(log)]) == 0
    capsys.readouterr()
    code, _, err = _run([str(log)], capsys)
    assert code == 2 and str(log) in err and "several operating points per log" in err


def test_mixed_sample_rates_of_one_rig_are_refused_naming_both_files(tmp_path, capsys):
    folder = tmp_path / "mixed"
    recs = [simulate_recording("ecore", 80.0, 1.27, 0.05, fs_hz=100_000.0, seed=1),
            simulate_recording("ecore", 320.0, 1.27, 0.05, fs_hz=50_000.0, seed=2)]
    write_sweep(recs, folder)
    code, out, err = _run([str(folder), "--report", str(tmp_path / "rep")], capsys)
    assert code == 2 and err.count("\n") == 1
    assert "ecore_80Hz" in err and "ecore_320Hz" in err and "sample rate" in err
    assert not (tmp_path / "rep").exists() and _no_stage_left(tmp_path)  # nothing half-written


@pytest.mark.parametrize("option", ["--baseline", "--candidates"])
def test_an_effect_outside_the_catalogue_is_refused_naming_option_and_name(day, option, capsys):
    code, out, err = _run([str(day[1]), option, "instrument_filter,magnet_creep"], capsys)
    assert code == 2 and out == ""
    assert f"argument {option}" in err and "'magnet_creep'" in err and "charge_amp_highpass" in err  # lists the known


def test_a_candidate_already_in_the_baseline_is_refused_naming_it(day, capsys):
    """``--baseline excess_loss --candidates excess_loss`` dropped the candidate silently and said
    "nothing significant left" at 6730 noise floors."""
    code, out, err = _run([str(day[1]), "--baseline", "static_hysteresis,excess_loss",
                           "--candidates", "excess_loss,instrument_filter"], capsys)
    assert code == 2 and out == "" and err.count("\n") == 1
    assert "--candidates: excess_loss already in every rig's baseline" in err and "instrument_filter" not in err


def test_a_recording_copied_under_another_name_is_refused_naming_both(day, tmp_path, capsys):
    """Copied into its own folder, a recording counted twice with no word (the best candidate moved
    from a skew to a frame mode), where the same folder given twice is refused."""
    import shutil

    folder = tmp_path / "sweep"
    shutil.copytree(day[0], folder)
    original = sorted(folder.glob("*.csv"))[0]
    for suffix in (".csv", ".json"):
        shutil.copy(original.with_suffix(suffix), folder / f"copy{suffix}")
    code, out, err = _run([str(folder)], capsys)
    assert code == 2 and out == "" and err.count("\n") == 1
    assert "the same samples as" in err and original.stem in err and "copy" in err


def test_a_sidecar_without_its_start_time_is_named(day, tmp_path, capsys):
    """One of the sidecars without start_time_s was reported as "the sidecars hold no start_time_s"."""
    import shutil

    folder = tmp_path / "sweep"
    shutil.copytree(day[0], folder)
    side = sorted(folder.glob("*.json"))[0]
    meta = json.loads(side.read_text())
    del meta["start_time_s"]
    side.write_text(json.dumps(meta))
    code, out, err = _run([str(folder), "--json"], capsys)
    n = len(list(folder.glob("*.json")))
    assert code == 0
    said = [w for w in json.loads(out)["warnings"] if "start_time_s" in w]
    assert said and said[0].startswith(f"1 of {n} sidecars hold no start_time_s ({side.with_suffix('')})"), said


def test_diagnose_dot_is_the_folder_it_is_run_in(day, capsys, monkeypatch):
    """``cd SWEEP && hystbench diagnose .`` was a traceback (the waveform check replaced the suffix of '.')."""
    monkeypatch.chdir(day[1])
    code, out, err = _run([".", "--json"], capsys)
    assert code == 0 and "Traceback" not in err and json.loads(out)["seconds"] > 0


def test_a_rig_the_presets_do_not_know_is_refused_naming_file_and_rig(tmp_path, capsys):
    folder = tmp_path / "odd"
    recs = [simulate_recording("ecore", f, 1.27, 0.05, seed=n) for n, f in enumerate((80.0, 320.0))]
    write_sweep(recs, folder)
    sidecar = folder / "ecore_80Hz_1.27App.json"
    meta = json.loads(sidecar.read_text())
    meta["rig"] = "ecore_xl"
    sidecar.write_text(json.dumps(meta))
    code, _, err = _run([str(folder)], capsys)
    assert code == 2 and str(sidecar) in err and "'ecore_xl'" in err


def test_missing_input_and_mixed_kinds_are_refused(day, tmp_path, capsys):
    code, _, err = _run([str(tmp_path / "nowhere")], capsys)
    assert code == 2 and str(tmp_path / "nowhere") in err
    table = Path(__file__).parents[1] / "data" / "real" / "magnet_N87_sine.csv"
    code, _, err = _run([str(day[1]), str(table)], capsys)
    assert code == 2 and str(table) in err and "loss table" in err


def test_an_existing_report_folder_is_refused_before_any_work(day, tmp_path, capsys):
    rep = tmp_path / "rep"
    rep.mkdir()
    (rep / "keep.txt").write_text("mine")
    code, out, err = _run([str(day[1]), str(day[2]), "--report", str(rep)], capsys)
    assert code == 2 and "--report" in err and "--overwrite" in err
    assert sorted(p.name for p in rep.iterdir()) == ["keep.txt"]


def test_a_day_without_flux_warns_what_cannot_be_located_and_goes_on(tmp_path, capsys):
    plan = BenchDayPlan((RigBlock.grid("voicecoil_ferrite", (20.0, 200.0, 1000.0), [1.0], periods=12.0,
                                       min_duration_s=0.02),))
    (folder,) = _write_day(tmp_path, plan)
    code, out, err = _run([str(folder), "--json"], capsys)
    assert code == 0
    assert "warning:" in err and "flux_Wb" in err and "going on with force vs current" in err
    doc = json.loads(out)
    assert ISSUE_KEYS <= set(doc) and doc["rigs"] == ["voicecoil_ferrite"]


def test_json_is_the_stable_document_and_the_report_is_written(day, tmp_path, capsys):
    rep = tmp_path / "rep"
    code, out, err = _run([*map(str, day), "--json", "--report", str(rep)], capsys)
    assert code == 0, err

    def no_nan(word):
        raise AssertionError(f"{word} in --json")

    doc = json.loads(out, parse_constant=no_nan)
    assert ISSUE_KEYS <= set(doc)
    assert LOCATED_KEYS <= set(doc["located"])
    assert doc["effect"] is None or doc["effect"] == doc["effects"][0]
    assert all({"name", "score", "parameters"} <= set(c) for c in doc["candidates"])
    assert doc["recordings"] == 10 and sorted(doc["rigs"]) == ["ecore", "ecore_pm", "voicecoil_ferrite"]
    page = (rep / "README.md").read_text()
    for heading in ("## 1. Calibration", "## 2. Where the mismatch is", "## 3. Candidates", "## 4. The model",
                    "## 5. Proof"):
        assert heading in page
    for png in ("heat_map.png", "loops.png"):
        assert (rep / png).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and f"]({png})" in page
    assert _no_stage_left(tmp_path)


def test_a_loss_table_goes_to_the_loss_separation(capsys):
    table = Path(__file__).parents[1] / "data" / "real" / "magnet_N87_sine.csv"
    code, out, err = _run([str(table), "--json"], capsys)
    assert code == 0, err
    doc = json.loads(out)
    assert doc["path"] == str(table) and {"effect", "effects", "residual_before", "residual_after"} <= set(doc)
    # the table shows both splits: the prescribed one, then across the band (its own figure in the row)
    code, out, err = _run([str(table)], capsys)
    rows = [line for line in out.splitlines() if "lowest" in line]
    assert code == 0 and len(rows) == 2 and "lowest third" in rows[0] and "lowest fifth + every" in rows[1]
    other = doc["other_split"]
    assert f"{other['residual_after_log10']:.3f}" in rows[1] and f"{other['improvement']:.2f}x" in rows[1]


REAL = Path(__file__).parents[1] / "data" / "real"


def test_a_materials_sine_and_shapes_tables_are_diagnosed_together(capsys):
    sine, shapes = REAL / "magnet_N87_sine.csv", REAL / "magnet_N87_shapes.csv"
    code, out, err = _run([str(shapes), str(sine), "--json"], capsys)
    assert code == 0, err
    doc = json.loads(out)  # one document: one group
    assert doc["paths"] == [str(sine), str(shapes)]
    assert {"sine", "triangle", "trapezoid"} == set(doc["shapes"]["groups"])
    assert {"effect", "effects", "residual_before", "residual_after"} <= set(doc)


def test_a_bad_shapes_table_is_refused_naming_the_file_and_a_report_of_shapes_is_drawn(tmp_path, capsys):
    lines = (REAL / "magnet_N87_shapes.csv").read_text().splitlines()[:41]
    lines[7] = lines[7].replace("0.1,0.0,0.9,0.0", "0.1,0.0,0.8,0.0")
    bad = tmp_path / "bad_shapes.csv"
    bad.write_text("\n".join(lines) + "\n")
    bad.with_suffix(".json").write_text((REAL / "magnet_N87_shapes.json").read_text())
    code, out, err = _run([str(REAL / "magnet_N87_sine.csv"), str(bad)], capsys)
    assert code == 2 and out == "" and err.count("\n") == 1 and f"{bad}:8" in err and "sum to" in err
    rep = tmp_path / "rep"  # a report of the shapes draws loss against frequency per shape group
    code, out, err = _run([str(REAL / "magnet_N87_sine.csv"), str(REAL / "magnet_N87_shapes.csv"), "--report",
                           str(rep)], capsys)
    assert code == 0 and sorted(p.name for p in rep.glob("*.png")) == ["loss_0_magnet_N87_sine.png"]
    assert "trapezoid" in next(rep.glob("*.md")).read_text() and _no_stage_left(tmp_path)


def test_a_folder_of_tables_and_shapes_without_their_sines_say_what_to_give(tmp_path, capsys):
    """A folder of material tables is not a bench day (its reader asked for a 'rig'); a shapes table
    without symmetric triangles, given alone, has nothing to calibrate the baseline on: each says what
    to give instead."""
    folder = tmp_path / "tables"
    folder.mkdir()
    for suffix in (".csv", ".json"):
        (folder / f"magnet_N87_sine{suffix}").write_bytes((REAL / f"magnet_N87_sine{suffix}").read_bytes())
    code, out, err = _run([str(folder)], capsys)
    assert code == 2 and f"{folder}: a folder of material tables (core_loss)" in err and f"{folder}/*.csv" in err
    lines = (REAL / "magnet_N87_shapes.csv").read_text().splitlines()
    kept = [lines[0]] + [x for x in lines[1:] if ",0.5,0.0,0.5,0.0," not in x][:3000]
    shapes = tmp_path / "shapes.csv"
    shapes.write_text("\n".join(kept) + "\n")
    shapes.with_suffix(".json").write_text((REAL / "magnet_N87_shapes.json").read_text())
    code, out, err = _run([str(shapes)], capsys)
    assert code == 2 and "0 calibration rows" in err and "give the material's sine table beside its shapes" in err
