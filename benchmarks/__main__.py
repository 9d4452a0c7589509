"""``python -m benchmarks NAME [ARGS]``: run one benchmark with its own arguments (``NAME --help``
shows them); without NAME, list them."""

from __future__ import annotations

import sys

from . import load, names


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv or argv[0] in ("-h", "--help"):
        print("usage: python -m benchmarks NAME [ARGS]   (NAME --help for its arguments)\n"
              f"benchmarks: {', '.join(names())}")
        return 0
    try:
        module = load(argv[0])
    except LookupError as err:
        print(f"python -m benchmarks: error: {err.args[0]}", file=sys.stderr)
        return 2
    return int(module.main(argv[1:]) or 0)


if __name__ == "__main__":
    sys.exit(main())
