"""``hystbench model fit|predict`` and ``hystbench compensate`` end to end (argparse as the CLI has it)."""

import contextlib
import io
import json

import numpy as np
import pytest

from hystbench.cli.main import main as run  # the hystbench command: BenchError -> exit 2
from hystbench.compensator.choice import SIMPLICITY
from hystbench.sim_backend.recordings import simulated_sweep
from hystbench.formats.recording import read_recording, write_recording, write_sweep

pytestmark = pytest.mark.slow(20)  # ~20 s: handed to a worker before lighter files (tests/conftest.py)


@pytest.fixture(scope="module")
def fitted(tmp_path_factory):
    """The model file of `model fit` on a small ecore_pm sweep, and what ``--json`` printed."""
    root = tmp_path_factory.mktemp("comp")
    write_sweep(simulated_sweep("ecore_pm", (80.0, 480.0), (0.4, 0.9, 1.5), seed=300), root / "sweep")
    out = root / "models.json"
    printed = io.StringIO()
    with contextlib.redirect_stdout(printed):
        assert run(["model", "fit", str(root / "sweep"), "--out", str(out), "--json"]) == 0
    return out, json.loads(printed.getvalue())


@pytest.fixture(scope="module")
def model_file(fitted):
    return fitted[0]


def test_model_fit_writes_all_three_models_and_names_the_chosen_description(fitted):
    model_file, said = fitted
    d = json.loads(model_file.read_text())
    assert d["rig"] == "ecore_pm" and set(d["models"]) == {"nonhysteretic", "paper", "best"}
    assert len(d["report"]["recordings"]) == 6
    best = [r["accuracy_pct"] for r in d["report"]["training_error"]["best"]]
    assert min(best) > 99.8
    assert said["best_description"] == d["report"]["choice"]["chosen"] in SIMPLICITY and said["why"]


def test_a_sweep_with_no_point_to_hold_out_is_refused_before_a_file_is_written(tmp_path, capsys):
    """Two recordings leave none to hold out: the choice's every figure was NaN, written bare into a
    model file (exit 0) that predict and compensate then refused."""
    write_sweep(simulated_sweep("ecore_pm", (80.0, 320.0), (1.4,), seed=301, duration_s=0.05), tmp_path / "two")
    out = tmp_path / "m.json"
    assert run(["model", "fit", str(tmp_path / "two"), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "these 2 recordings" in err and "leave none to hold out: record more frequencies or amplitudes" in err
    assert not out.exists()


def test_model_predict_writes_time_and_force(model_file, tmp_path, capsys):
    rec = simulated_sweep("ecore_pm", [320.0], [1.0], seed=77, duration_s=0.2)[0]
    write_recording(rec, tmp_path / "r320")
    out = tmp_path / "pred.csv"
    assert run(["model", "predict", str(model_file), str(tmp_path / "r320.csv"), "--kind", "best", "--out", str(out)]) == 0
    assert "wrote" in capsys.readouterr().out
    assert out.read_text().splitlines()[0] == "time_s,force_N"
    data = np.loadtxt(out, delimiter=",", skiprows=1)
    back = read_recording(tmp_path / "r320.csv")
    assert data.shape == (back.n, 2)
    assert data[:, 0] == pytest.approx(back.time_s())
    resid = back.channels["force_N"] - data[:, 1]
    assert np.std(resid) < 0.04 and abs(np.mean(resid)) < 0.01  # the sensor's 0.03 N noise, nothing more
    assert run(["model", "predict", str(model_file), str(tmp_path / "r320.csv"), "--out", str(out)]) == 2
    assert "exists; give --overwrite" in capsys.readouterr().err
    # --overwrite onto what the command reads (the recording, given by its stem; the model) is refused
    samples, model = (tmp_path / "r320.csv").read_bytes(), model_file.read_bytes()
    for target in (tmp_path / "r320.csv", model_file):
        assert run(["model", "predict", str(model_file), str(tmp_path / "r320"), "--out", str(target), "--overwrite"]) == 2
        assert f"--out {target}: the command reads" in capsys.readouterr().err
    assert (tmp_path / "r320.csv").read_bytes() == samples and model_file.read_bytes() == model


def test_model_fit_writes_nothing_into_the_sweep_it_reads(fitted, capsys):
    sweep = fitted[0].parent / "sweep"
    sidecar = next(sweep.glob("*.json"))
    before = sidecar.read_bytes()
    assert run(["model", "fit", str(sweep), "--out", str(sidecar), "--overwrite"]) == 2
    assert f"--out {sidecar}: the command reads {sweep}" in capsys.readouterr().err
    assert sidecar.read_bytes() == before


def test_model_predict_refuses_another_rigs_recording(model_file, tmp_path, capsys):
    rec = simulated_sweep("ecore", [320.0], [1.0], seed=1, duration_s=0.05)[0]
    write_recording(rec, tmp_path / "other")
    assert run(["model", "predict", str(model_file), str(tmp_path / "other.csv"), "--out", str(tmp_path / "p.csv")]) == 2
    assert "a 'ecore' recording, but the models are of 'ecore_pm'" in capsys.readouterr().err


def test_model_predict_refuses_a_sidecar_frequency_the_current_is_not_at(model_file, tmp_path, capsys):
    """A 320 Hz recording labelled 100 Hz was predicted at 100 Hz, exit 0, 33 N rms off."""
    rec = simulated_sweep("ecore_pm", [320.0], [1.4], seed=2, duration_s=0.05)[0]
    rec.metadata["frequency_Hz"] = 100.0
    rec.metadata.pop("generator_frequency_Hz", None)
    write_recording(rec, tmp_path / "wrong")
    assert run(["model", "predict", str(model_file), str(tmp_path / "wrong.csv"), "--out", str(tmp_path / "p.csv")]) == 2
    assert ("channel 'current_A' has no clear component at 100 Hz" in (err := capsys.readouterr().err)
            and "spectrum peaks at 320 Hz" in err and not (tmp_path / "p.csv").exists())


def test_compensate_learns_and_reports_each_iteration(model_file, capsys):
    argv = ["compensate", "--rig", "ecore_pm", "--force", "offset=170,amp=40,freq=320", "--learn", "--iterations", "3",
            "--model", str(model_file), "--json"]
    assert run(argv) == 0
    out = json.loads(capsys.readouterr().out)
    its = out["iterations"]
    assert [r["iteration"] for r in its] == [0, 1, 2, 3]
    assert its[-1]["ratio"] < 2.0 and its[-1]["max_error_n"] < its[0]["max_error_n"]
    assert out["output_on"] is False and "through the drivers" in out["driven_through"]


@pytest.mark.parametrize("argv, message", [
    (["--rig", "ecore", "--force", "offset=0.5,amp=1,freq=320"], "only attracts"),
    (["--rig", "ecore_pm", "--force", "offset=170,amp=150,freq=320"], "above the 1.71 A limit; reachable"),
    (["--rig", "ecore_pm", "--force", "offset=170,amp=40"], "missing freq="),
    (["--rig", "ecore_pm"], "give --force"),
    (["--rig", "ecore_pm", "--force-file", "x.csv"], "--force-file needs --freq"),
    (["--rig", "ecore_pm", "--force", "offset=170,amp=40,freq=320", "--force-file", "x.csv", "--freq", "320"],
     "--force and --force-file: give one force reference, not both"),  # the file was taken without a word
    (["--rig", "ecore", "--force", "offset=2,amp=1,freq=320"], "models of 'ecore_pm', but --rig is 'ecore'"),
    (["--rig", "ecore_pm", "--force", "offset=170,amp=40,freq=320", "--iterations", "100000"], "--iterations"),
    # ignored before: the run was at 320 Hz
    (["--rig", "ecore_pm", "--force", "offset=170,amp=40,freq=320", "--freq", "100"], "--freq goes with --force-file"),
    # a component the table aliases, one no 100 kS/s bench can sample: each was reported "tracked"
    (["--rig", "ecore_pm", "--force", "offset=170,amp=40,freq=320,h99999999999=1"],
     "harmonic 99999999999 is beyond what a period of 1000 points holds (below 500)"),
    (["--rig", "ecore_pm", "--force", "offset=170,amp=40,freq=20000,h3=1"],
     "it holds 60000 Hz, at or above half the bench's 100000 S/s"),
])
def test_compensate_refuses_what_the_actuator_cannot_do(model_file, capsys, argv, message):
    assert run(["compensate", *argv, "--model", str(model_file)]) == 2
    assert message in capsys.readouterr().err


def test_model_fit_takes_the_instrument_from_a_voice_coil_sweep_on_the_same_load_cell(tmp_path, capsys):
    """A bench whose load cell is not the preset's (fn 4 % low, damping x1.3): `model fit
    --instrument-sweep` fits the instrument from the voice coil's sweep and the models use it (the
    paper's Eq. 6 alone: the instrument is what is under test, not the choice of description)."""
    from hystbench.sim_backend.benches import foreign_preset, voice_coil_on_load_cell
    from hystbench.sim_backend.recordings import simulate_voice_coil_sweep

    bench = foreign_preset("ecore_pm~m130")  # its instrument: fn x0.96, zeta_n x1.3
    write_sweep(simulate_voice_coil_sweep(voice_coil_on_load_cell(bench), np.geomspace(10.0, 45000.0, 16), seed=3,
                                          samples_per_period=100.0), tmp_path / "vc")
    write_sweep(simulated_sweep(bench, (40.0, 480.0), (0.4, 1.5), seed=310), tmp_path / "sweep")  # the instrument is under test
    out = tmp_path / "m.json"
    assert run(["model", "fit", str(tmp_path / "sweep"), "--out", str(out), "--instrument-sweep",
                str(tmp_path / "vc"), "--kinds", "paper", "--json"]) == 0
    said = json.loads(capsys.readouterr().out)
    ins = json.loads(out.read_text())["instrument"]
    assert said["instrument"] == {k: ins[k] for k in ("fn_Hz", "zeta_n")}
    assert ins["fn_Hz"] == pytest.approx(bench["instrument"]["fn_hz"], rel=2e-3)
    assert ins["zeta_n"] == pytest.approx(bench["instrument"]["zeta_n"], rel=0.05)
    assert run(["model", "fit", str(tmp_path / "sweep"), "--out", str(tmp_path / "n.json"),
                "--instrument-sweep", str(tmp_path / "nothing")]) == 2
    assert "nothing" in capsys.readouterr().err
