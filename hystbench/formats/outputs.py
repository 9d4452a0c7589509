"""Output files of a command: all or nothing.

A command that fails half-way (bad input found late, a full disk, Ctrl-C) must leave no partial
file behind, and must not replace a file the user did not ask to replace.  So every output is
written under a temporary name beside its target (same folder, so the final rename is atomic) and
renamed into place only when the command succeeded; an existing target is refused up front, before
any work, unless ``--overwrite``.

    with output_file(args.out, overwrite=args.overwrite) as tmp:      # one file (keeps the suffix)
        fig.savefig(tmp)
    with output_folder(args.out, overwrite=args.overwrite) as stage:  # a folder of files
        draw(stage.path)                                              # then stage.final(p) names p's target
"""

from __future__ import annotations

import errno
import os
import secrets
import shutil
from contextlib import contextmanager
from pathlib import Path
from typing import Iterable, Iterator

from ..errors import BenchError, ConfigError, RecordingError

__all__ = ["output_file", "output_folder", "parent_folders", "StagedFolder"]


def _make_parent(path: Path, option: str) -> list[Path]:
    """Create ``path``'s missing parent folders; returns those created (deepest last)."""
    made: list[Path] = []
    missing = [p for p in reversed(path.parents) if not p.exists()]
    for folder in missing:
        try:
            folder.mkdir()
        except FileExistsError:  # made meanwhile by another writer (two reports into one new folder)
            if folder.is_dir():
                continue
            _remove_folders(made)
            raise RecordingError(f"{option} {path}: cannot create the folder {folder}: a file has that name") from None
        except OSError as err:
            _remove_folders(made)
            raise RecordingError(f"{option} {path}: cannot create the folder {folder}: {err.strerror}") from err
        made.append(folder)
    parent = path.parent
    if not parent.is_dir():
        raise RecordingError(f"{option} {path}: {parent} is not a folder")
    return made


def _named_as_final(err: BenchError, temporary: Path, final: Path) -> None:
    """Let ``err`` (raised by a writer that was handed the temporary name) name ``final`` instead:
    the user never gave, and will never find, the hidden temporary."""
    if err.args and isinstance(err.args[0], str) and str(temporary) in err.args[0]:
        err.args = (err.args[0].replace(str(temporary), str(final)), *err.args[1:])


def _remove_folders(made: list[Path]) -> None:
    for folder in reversed(made):
        try:
            folder.rmdir()
        except OSError:
            pass


@contextmanager
def parent_folders(path: str | Path, *, option: str = "--out") -> Iterator[None]:
    """``path``'s missing parent folders, made for a writer that stages its own files (a recording's
    pair), and removed again if the block fails: a name the filesystem refuses leaves no empty folder."""
    made = _make_parent(Path(path), option)
    try:
        yield
    except BaseException:
        _remove_folders(made)
        raise


def _refuse_inputs(path: Path, inputs: Iterable[str | Path], option: str) -> None:
    """An output may not be an input of the same command, nor be written into an input folder: with
    ``--overwrite`` it would destroy what the command reads (a recording's samples, a sweep's sidecar)."""
    inputs = list(inputs)
    if not inputs:
        return
    target = path.resolve()
    for given in inputs:
        p = Path(given).resolve()
        if target == p or (p.is_dir() and p in target.parents) or (target.is_dir() and target in p.parents):
            raise ConfigError(f"{option} {path}: the command reads {given}; write its output elsewhere")


@contextmanager
def output_file(path: str | Path, *, overwrite: bool = False, option: str = "--out",
                inputs: Iterable[str | Path] = ()) -> Iterator[Path]:
    """A temporary path beside ``path`` (same suffix, so writers that go by it still do); renamed
    onto ``path`` when the block ends normally, removed (with any folder made for it) otherwise.
    ``inputs``: what the command reads, refused as the output or a folder it goes into."""
    path = Path(path)
    _refuse_inputs(path, inputs, option)
    if path.is_dir():
        raise ConfigError(f"{option} {path}: is a folder; give a file name")
    if path.exists() and not overwrite:
        raise ConfigError(f"{option} {path}: exists; give --overwrite to replace it")
    made = _make_parent(path, option)
    tmp = path.with_name(f".{path.stem}.{secrets.token_hex(4)}.tmp{path.suffix}")
    try:
        yield tmp
        if not tmp.exists():
            raise RecordingError(f"{option} {path}: nothing was written")
        os.replace(tmp, path)
    except OSError as err:
        raise RecordingError(f"{option} {path}: cannot write: {err.strerror or err}") from err
    except BenchError as err:
        _named_as_final(err, tmp, path)
        raise
    finally:
        tmp.unlink(missing_ok=True)
        if not path.exists():
            _remove_folders(made)


class StagedFolder:
    """A hidden folder beside the target where a command writes its files."""

    def __init__(self, target: Path, path: Path) -> None:
        self.target = target
        self.path = path

    def final(self, written: str | Path) -> Path:
        """Where a file written under :attr:`path` ends up."""
        return self.target / Path(written).relative_to(self.path)


@contextmanager
def output_folder(path: str | Path, *, overwrite: bool = False, option: str = "--out",
                  inputs: Iterable[str | Path] = ()) -> Iterator[StagedFolder]:
    """A folder to write into; when the block ends normally its files move into ``path`` (made if
    missing), each by an atomic rename; otherwise it is removed and ``path`` is as it was.

    An existing ``path`` that holds anything is refused unless ``overwrite`` (then files of the
    same name are replaced, others kept); so is one that is, holds or lies in one of ``inputs``."""
    target = Path(path)
    _refuse_inputs(target, inputs, option)
    if target.exists() and not target.is_dir():
        raise ConfigError(f"{option} {target}: is a file, not a folder")
    if target.is_dir() and not overwrite and any(target.iterdir()):
        raise ConfigError(f"{option} {target}: exists and is not empty; give --overwrite to write into it")
    made = _make_parent(target, option)
    stage = target.with_name(f".{target.name}.{secrets.token_hex(4)}.tmp")
    try:
        stage.mkdir()
    except OSError as err:
        _remove_folders(made)
        raise RecordingError(f"{option} {target}: cannot write beside it: {err.strerror}") from err
    created = not target.exists()
    try:
        staged = StagedFolder(target, stage)
        try:
            yield staged
        except OSError as err:
            full = err.filename is None and err.errno in (errno.ENOSPC, errno.EDQUOT, errno.EFBIG)  # a write's, unnamed
            if full:
                raise RecordingError(f"{option} {target}: cannot write: {err.strerror}") from err
            if not _under(err.filename, stage):  # not a write of ours (an input, say): as it came
                raise
            # a writer's: named by where its file was going, not by the hidden stage
            raise RecordingError(f"{option} {target}: cannot write {staged.final(err.filename)}: "
                                 f"{err.strerror or type(err).__name__}") from err
        except BenchError as err:
            _named_as_final(err, stage, target)
            raise
        try:
            if created:
                os.replace(stage, target)
            else:
                for src in sorted(p for p in stage.rglob("*") if p.is_file()):
                    dest = target / src.relative_to(stage)
                    dest.parent.mkdir(parents=True, exist_ok=True)
                    os.replace(src, dest)
        except OSError as err:
            raise RecordingError(f"{option} {target}: cannot write: {err.strerror or err}") from err
    finally:
        shutil.rmtree(stage, ignore_errors=True)
        if not target.exists():
            _remove_folders(made)


def _under(name, folder: Path) -> bool:
    """Whether the path ``name`` (an OSError's filename, maybe None) lies in ``folder``."""
    try:
        Path(name).relative_to(folder)
    except (TypeError, ValueError):
        return False
    return True
