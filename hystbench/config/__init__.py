"""TOML presets shipped with the package: rigs (``rigs/*.toml``) and materials (``materials/*.toml``).

Loading returns plain dicts; each consumer builds its typed objects from them and reports a bad key
through :func:`require`, so every message names the file and the key.
"""

from __future__ import annotations

import os
import tomllib
from pathlib import Path
from typing import Any

from ..errors import ConfigError

__all__ = ["CONFIG_DIR", "read_toml", "shared_data_dir", "rig_names", "load_rig", "material_names", "load_material", "require"]

CONFIG_DIR = Path(__file__).resolve().parent


def shared_data_dir() -> Path:
    """``shared/data`` beside the checkout (real measured material data), or $HYSTBENCH_SHARED_DIR/data."""
    root = os.environ.get("HYSTBENCH_SHARED_DIR")
    base = Path(root) if root else CONFIG_DIR.parents[2] / "shared"
    data = base / "data"
    if not data.is_dir():
        raise ConfigError(f"shared data folder {data} not found; set HYSTBENCH_SHARED_DIR to the shared/ folder")
    return data


def _names(folder: str) -> list[str]:
    return sorted(p.stem for p in (CONFIG_DIR / folder).glob("*.toml"))


def rig_names() -> list[str]:
    """The rig presets, which are also the legal values of a recording's ``rig`` key."""
    return _names("rigs")


def material_names() -> list[str]:
    return _names("materials")


def read_toml(path: str | Path, what: str = "file") -> dict[str, Any]:
    """A TOML file as a dict; a missing or malformed file is a ConfigError naming it."""
    path = Path(path)
    try:
        with path.open("rb") as fh:
            return tomllib.load(fh)
    except FileNotFoundError as err:
        raise ConfigError(f"{path}: no such {what}") from err
    except tomllib.TOMLDecodeError as err:
        raise ConfigError(f"{path}: not valid TOML: {err}") from err


def _load(folder: str, name_or_path: str | Path) -> dict[str, Any]:
    path = Path(name_or_path)
    if path.suffix != ".toml":
        path = CONFIG_DIR / folder / f"{name_or_path}.toml"
        if not path.exists():
            raise ConfigError(
                f"unknown {folder[:-1]} {str(name_or_path)!r}; known: {', '.join(_names(folder))}"
            )
    data = read_toml(path)
    data.setdefault("name", path.stem)
    data["_source"] = str(path)
    return data


def load_rig(name_or_path: str | Path) -> dict[str, Any]:
    """A rig preset by name (``ecore_pm``) or by path to a TOML file of the same form."""
    return _load("rigs", name_or_path)


def load_material(name_or_path: str | Path) -> dict[str, Any]:
    return _load("materials", name_or_path)


def require(table: dict[str, Any], key: str, where: str, kind: type | tuple[type, ...] = (int, float)):
    """``table[key]``, checked for type; ``where`` is the file and table path, e.g. 'ecore.toml [coil]'."""
    if key not in table:
        raise ConfigError(f"{where}: missing key {key!r}")
    value = table[key]
    if isinstance(value, bool) or not isinstance(value, kind):
        raise ConfigError(f"{where}: key {key!r} must be {kind}, got {value!r}")
    return value
