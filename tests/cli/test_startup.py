"""A command line starts without scipy: ``hystbench ctl status`` or ``watch`` is typed often and
runs in scripts, and importing scipy.constants alone took 0.3 s of the 0.4 s it started in.  What a
command needs of scipy it imports when it runs."""

from __future__ import annotations

import subprocess
import sys

import scipy.constants

from hystbench.config.presets import MU_0


def test_the_command_line_imports_no_scipy_before_a_command_runs():
    probe = "import sys, hystbench.cli.main; print(sorted(m for m in sys.modules if m.split('.')[0] == 'scipy'))"
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=60, check=True)
    assert out.stdout.strip() == "[]", out.stdout


def test_the_written_out_vacuum_permeability_is_scipys():
    assert MU_0 == scipy.constants.mu_0
