"""``python -m hystbench`` is the ``hystbench`` command."""

import sys

from .acquisition.cli import main

sys.exit(main())
