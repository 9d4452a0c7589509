"""The one rich console every command prints through, and the progress bar of long work."""

from __future__ import annotations

import sys

from rich.console import Console
from rich.progress import Progress, TimeElapsedColumn

__all__ = ["console", "progress"]


def console() -> Console:
    """A terminal's own width; 120 columns when piped or logged (rich would fold tables at 80)."""
    return Console(width=None if sys.stdout.isatty() else 120)


def progress() -> Progress:
    """A transient progress bar on stderr, so that stdout (tables, JSON) stays clean when piped;
    off when stderr is not a terminal (a log, a pipe, a test): nothing to erase there."""
    err = Console(stderr=True)
    # stdout goes through the bar's terminal only when it IS a terminal; into a pipe it stays stdout
    return Progress(*Progress.get_default_columns(), TimeElapsedColumn(), console=err, transient=True,
                    disable=not err.is_terminal, redirect_stdout=sys.stdout.isatty())
