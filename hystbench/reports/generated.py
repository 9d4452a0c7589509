"""Files the project generates and commits (docs/config.md, the Foxglove layout): one command line
that writes them or, with ``--check``, says they drifted from what generates them."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Callable

__all__ = ["generated_file_main"]


def generated_file_main(argv: list[str] | None, *, command: str, description: str, default: Path,
                        render: Callable[[], str]) -> int:
    """``COMMAND [PATH] [--check]``: write ``render()`` to PATH (default ``default``); with --check,
    only compare and exit 1 if the file is out of date."""
    ap = argparse.ArgumentParser(prog=command, description=description)
    ap.add_argument("path", nargs="?", type=Path, default=default, help=f"where to write (default: {default.name})")
    ap.add_argument("--check", action="store_true", help="only compare; exit 1 if the file is out of date")
    a = ap.parse_args(argv)
    text = render()
    if a.check:
        if (a.path.read_text(encoding="utf-8") if a.path.exists() else "") != text:
            print(f"{a.path} is out of date: run {command}", file=sys.stderr)
            return 1
        return 0
    a.path.write_text(text, encoding="utf-8")
    print(f"wrote {a.path}")
    return 0
