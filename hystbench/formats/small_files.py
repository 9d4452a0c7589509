"""Bounded reads of the small files beside the samples: JSON sidecars and material tables.

Why: these files are read whole, so their size must be bounded before they are read (a sidecar
of a few keys that turns out to be gigabytes would otherwise be held, decoded and parsed in
memory), and every way a JSON parser can fail (nesting deeper than the interpreter's stack, an
integer of more digits than Python converts) must become a :class:`RecordingError` naming the
file, not a traceback.  Values quoted in messages are cut to a few dozen characters, so an error
about a 500 kB field is still one line.
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import Any

from ..errors import RecordingError

__all__ = ["MAX_SIDECAR_BYTES", "MAX_TABLE_BYTES", "excerpt", "finite", "shown", "read_json", "read_text"]

#: The largest JSON sidecar read (4 MiB).  A sidecar holds a few keys and some notes: a few kB.
MAX_SIDECAR_BYTES = 4 << 20
#: The largest material table (CSV) read whole (16 MiB).  The vendored tables are under 400 kB.
MAX_TABLE_BYTES = 16 << 20
_EXCERPT_CHARS = 40


def excerpt(text: str, limit: int = _EXCERPT_CHARS) -> str:
    """``repr(text)``, or of its first ``limit`` characters followed by how long it is."""
    return repr(text) if len(text) <= limit else f"{text[:limit]!r}... ({len(text)} characters)"


def shown(value: Any, limit: int = _EXCERPT_CHARS) -> str:
    """``repr(value)``, cut to ``limit`` characters followed by how long it is (a 400-digit number
    in a refusal is one line, not a screenful)."""
    text = repr(value)
    return text if len(text) <= limit else f"{text[:limit]}... ({len(text)} characters)"


def finite(v: float) -> bool:
    """Whether the number ``v`` is finite as a float: a JSON integer of 400 digits is not (math.isfinite
    raised OverflowError on it, a traceback instead of the key's error)."""
    try:
        return math.isfinite(v)
    except OverflowError:
        return False


def read_text(path: Path, max_bytes: int, what: str, limit_name: str) -> str:
    """The UTF-8 text of ``path`` with '\\n' line ends, refused unread past ``max_bytes``."""
    if os.path.exists(path) and not os.path.isfile(path):  # a FIFO with no writer would block the open for ever
        raise RecordingError(f"{path}: not a regular file (a folder, pipe or device); a {what} is a file")
    try:
        with open(path, "rb") as fh:
            raw = fh.read(max_bytes + 1)  # not the size on disk: a pipe or device has none
    except OSError as err:
        raise RecordingError(f"{path}: cannot read: {err.strerror}") from err
    if len(raw) > max_bytes:
        raise RecordingError(f"{path}: larger than {max_bytes} bytes; a {what} is much smaller ({limit_name})")
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError as err:
        line = raw.count(b"\n", 0, err.start) + 1
        raise RecordingError(f"{path}:{line}: not UTF-8 (byte {err.start})") from err
    return text.replace("\r\n", "\n").replace("\r", "\n")


def _unique_keys(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    """json.loads keeps the last of two equal keys; here that is an error."""
    out: dict[str, Any] = {}
    for key, value in pairs:
        if key in out:
            raise RecordingError(f"key {excerpt(key)} appears twice")
        out[key] = value
    return out


def _no_constant(name: str) -> None:
    """json.loads accepts NaN and Infinity, which are not JSON and could not be written back."""
    raise RecordingError(f"{name} is not valid JSON; write a number or null")


def read_json(path: Path, max_bytes: int = MAX_SIDECAR_BYTES, what: str = "sidecar",
              limit_name: str = "MAX_SIDECAR_BYTES") -> Any:
    """The JSON value in ``path`` (strict: no repeated keys, no NaN/Infinity), at most ``max_bytes``."""
    text = read_text(path, max_bytes, what, limit_name)
    try:
        return json.loads(text, object_pairs_hook=_unique_keys, parse_constant=_no_constant)
    except json.JSONDecodeError as err:
        raise RecordingError(f"{path}:{err.lineno}: column {err.colno}: not valid JSON ({err.msg})") from err
    except RecordingError as err:
        raise RecordingError(f"{path}: {err}") from None
    except RecursionError as err:
        raise RecordingError(f"{path}: JSON nested too deeply to read; a {what} is a flat object") from err
    except ValueError as err:  # e.g. an integer of more digits than int() converts
        raise RecordingError(f"{path}: not valid JSON ({err})") from err
