"""TOML presets shipped with the package: rigs (``rigs/*.toml``) and materials (``materials/*.toml``),
and the one TOML reader every file of the service goes through.

Loading checks a preset against its schema (:mod:`.presets`, with :func:`.schema.check_table`, the
validator the bench file and the daemon file use too) and returns a plain dict with the defaults
filled in; a bad key is refused at load, naming the file, the table and the key.
"""

from __future__ import annotations

import os
import tomllib
from pathlib import Path
from typing import Any, Mapping

from ..errors import ConfigError
from .presets import check_material, check_rig

__all__ = ["CONFIG_DIR", "read_toml", "rig_names", "load_rig", "material_names",
           "load_material", "check_rig", "check_material"]

CONFIG_DIR = Path(__file__).resolve().parent


def _names(folder: str) -> list[str]:
    return sorted(p.stem for p in (CONFIG_DIR / folder).glob("*.toml"))


def rig_names() -> list[str]:
    """The rig presets, which are also the legal values of a recording's ``rig`` key."""
    return _names("rigs")


def material_names() -> list[str]:
    """The shipped materials, by name: what a rig preset's ``material`` may say."""
    return _names("materials")


def read_toml(path: str | Path, what: str = "file") -> dict[str, Any]:
    """A TOML file as a dict; a missing, unreadable or malformed file is a ConfigError naming it."""
    path = Path(path)
    if os.path.exists(path) and not os.path.isfile(path):  # a FIFO with no writer would block the open for ever
        raise ConfigError(f"{path}: not a regular file (a folder, pipe or device); cannot read the {what}")
    try:
        with path.open("rb") as fh:
            raw = fh.read()
        # a byte-order mark (an editor's UTF-8 "with BOM") is no TOML: tomllib said "Invalid statement
        # (at line 1, column 1)"; the text after it is what the file says
        return tomllib.loads(raw.removeprefix(b"\xef\xbb\xbf").decode("utf-8"))
    except FileNotFoundError as err:
        raise ConfigError(f"{path}: no such {what}") from err
    except tomllib.TOMLDecodeError as err:
        raise ConfigError(f"{path}: not valid TOML: {err}") from err
    except (OSError, UnicodeDecodeError) as err:
        raise ConfigError(f"{path}: cannot read the {what}: {err}") from err


def _path(folder: str, name_or_path: str | Path) -> Path:
    """A preset's file: a ``.toml`` path as given, or a name in the package's ``folder``."""
    path = Path(name_or_path)
    if path.suffix != ".toml":
        path = CONFIG_DIR / folder / f"{name_or_path}.toml"
        if not path.exists():
            raise ConfigError(
                f"unknown {folder[:-1]} {str(name_or_path)!r}; known: {', '.join(_names(folder))}"
            )
    return path


def _read(folder: str, name_or_path: str | Path) -> dict[str, Any]:
    path = _path(folder, name_or_path)
    data = read_toml(path)
    data.setdefault("name", path.stem)
    data["_source"] = str(path)
    return data


def load_rig(name_or_path: str | Path | Mapping[str, Any]) -> dict[str, Any]:
    """A rig preset by name (``ecore_pm``) or by path to a TOML file of the same form, checked
    against its actuator's schema (an already loaded preset, a dict, is checked again)."""
    data = dict(name_or_path) if isinstance(name_or_path, Mapping) else _read("rigs", name_or_path)
    rig = check_rig(data)
    iron = rig.get("iron")
    if iron is not None:
        try:
            path = _path("materials", iron["material"])
        except ConfigError as err:
            raise ConfigError(f"{rig['_source']} [iron] material: {err}") from None
        if not path.is_file():
            raise ConfigError(f"{rig['_source']} [iron] material: no such material file {str(path)!r}")
    return rig


def load_material(name_or_path: str | Path) -> dict[str, Any]:
    """A material file by name (``M330-50A``) or path, checked against the material schema."""
    return check_material(_read("materials", name_or_path))
