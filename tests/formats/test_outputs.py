"""All-or-nothing outputs (issue 10): a command that fails leaves no partial file or folder."""

import pytest

from hystbench.formats.outputs import output_file, output_folder
from hystbench.errors import ConfigError, RecordingError


def test_a_file_appears_only_when_the_block_succeeds(tmp_path):
    out = tmp_path / "a" / "b" / "x.csv"
    with pytest.raises(RecordingError, match="late failure"):
        with output_file(out) as tmp:
            assert tmp.parent == out.parent and tmp.suffix == ".csv"  # same folder: an atomic rename
            tmp.write_text("half")
            raise RecordingError("late failure")
    assert list(tmp_path.iterdir()) == []  # neither the file nor the folders made for it
    with output_file(out) as tmp:
        tmp.write_text("whole")
    assert out.read_text() == "whole" and sorted(p.name for p in out.parent.iterdir()) == ["x.csv"]


def test_an_existing_file_is_replaced_only_with_overwrite(tmp_path):
    out = tmp_path / "x.txt"
    out.write_text("old")
    with pytest.raises(ConfigError, match=r"x.txt: exists; give --overwrite"):
        with output_file(out):
            raise AssertionError("the block must not run")
    with output_file(out, overwrite=True) as tmp:
        tmp.write_text("new")
    assert out.read_text() == "new"


def test_a_folder_moves_into_place_whole_or_not_at_all(tmp_path):
    target = tmp_path / "report"
    with pytest.raises(RecordingError):
        with output_folder(target) as stage:
            (stage.path / "fig1.png").write_bytes(b"1")
            raise RecordingError("figure 2 failed")
    assert list(tmp_path.iterdir()) == []
    with output_folder(target) as stage:
        (stage.path / "fig1.png").write_bytes(b"1")
        (stage.path / "sub").mkdir()
        (stage.path / "sub" / "data.json").write_text("{}")
        assert stage.final(stage.path / "sub" / "data.json") == target / "sub" / "data.json"
    assert sorted(p.relative_to(target).as_posix() for p in target.rglob("*")) == ["fig1.png", "sub",
                                                                                   "sub/data.json"]
    assert [p.name for p in tmp_path.iterdir()] == ["report"]


def test_a_non_empty_folder_is_written_into_only_with_overwrite(tmp_path):
    target = tmp_path / "report"
    target.mkdir()
    (target / "keep.txt").write_text("mine")
    with pytest.raises(ConfigError, match="not empty; give --overwrite"):
        with output_folder(target):
            raise AssertionError("the block must not run")
    with output_folder(target, overwrite=True) as stage:
        (stage.path / "new.txt").write_text("new")
    assert sorted(p.name for p in target.iterdir()) == ["keep.txt", "new.txt"]
    assert (target / "keep.txt").read_text() == "mine"


def test_a_file_where_a_folder_should_be_is_one_clear_error(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    for make in (lambda: output_file(blocker / "deeper" / "x.png"), lambda: output_folder(blocker)):
        with pytest.raises((ConfigError, RecordingError), match=str(blocker)):
            with make():
                raise AssertionError("the block must not run")
    assert [p.name for p in tmp_path.iterdir()] == ["file"]


def test_a_parent_folder_made_meanwhile_by_another_writer_is_used(tmp_path, monkeypatch):
    """Two reports written at once into one new folder (the diagnosis benchmark's two workers): the
    second finds the folder missing, then made by the first when it tries to make it.  It writes into
    it, and a writer that fails afterwards does not remove the folder it did not make."""
    import pathlib

    shared = tmp_path / "runs"
    real_exists = pathlib.Path.exists

    def made_meanwhile(self, *args, **kwargs):
        if self == shared and not real_exists(self):
            self.mkdir()  # the other writer, between the check and the mkdir
            return False
        return real_exists(self, *args, **kwargs)

    monkeypatch.setattr(pathlib.Path, "exists", made_meanwhile)
    with output_folder(shared / "case_a") as stage:
        (stage.path / "report.md").write_text("a")
    assert (shared / "case_a" / "report.md").read_text() == "a"

    shared = tmp_path / "again"  # the same race, and this writer fails: the folder is the other's
    with pytest.raises(RuntimeError):
        with output_folder(shared / "case_b"):
            raise RuntimeError("the writer fails")
    assert shared.is_dir() and not (shared / "case_b").exists()


def test_an_input_is_never_an_output(tmp_path):
    """What the command reads is refused as its output, or as a folder the output goes into, even with
    --overwrite; an output folder that holds an input is refused too (a sweep written over its source)."""
    sweep = tmp_path / "sweep"
    sweep.mkdir()
    (sweep / "a.csv").write_text("x")
    for out in (sweep / "a.csv", sweep / "model.json"):
        with pytest.raises(ConfigError, match=f"--out {out}: the command reads"):
            with output_file(out, overwrite=True, inputs=[sweep]):
                pass
    with pytest.raises(ConfigError, match="the command reads"):
        with output_folder(tmp_path, overwrite=True, inputs=[sweep / "a.csv"]):
            pass
    with output_file(tmp_path / "elsewhere.json", inputs=[sweep]) as tmp:  # beside it: fine
        tmp.write_text("y")
    assert (sweep / "a.csv").read_text() == "x" and (tmp_path / "elsewhere.json").read_text() == "y"


def test_a_full_disk_under_a_folder_names_the_output(tmp_path):
    """A write that fills the disk raises ENOSPC with no file name (a stream's write, a figure's): the
    error names the output, not only '[Errno 28] No space left on device' (``paper`` said just that)."""
    import errno

    with pytest.raises(RecordingError, match=f"--out {tmp_path / 'rep'}: cannot write: No space left on device"):
        with output_folder(tmp_path / "rep") as stage:
            (stage.path / "a.txt").write_text("half")
            raise OSError(errno.ENOSPC, "No space left on device")
    assert sorted(p.name for p in tmp_path.iterdir()) == []
