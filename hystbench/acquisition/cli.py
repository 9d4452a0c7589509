"""The ``hystbench`` command line (placeholder until the subcommands land in this session)."""

from __future__ import annotations

import sys


def main(argv: list[str] | None = None) -> int:
    print("hystbench: no subcommands yet", file=sys.stderr)
    return 2
