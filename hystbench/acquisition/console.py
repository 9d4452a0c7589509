"""The one rich console every command prints through."""

from __future__ import annotations

import sys

from rich.console import Console

__all__ = ["console"]


def console() -> Console:
    """A terminal's own width; 120 columns when piped or logged (rich would fold tables at 80)."""
    return Console(width=None if sys.stdout.isatty() else 120)
