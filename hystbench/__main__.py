"""``python -m hystbench`` is the ``hystbench`` command."""

import sys

from .cli.main import main

sys.exit(main())
