"""What the command line refuses is a specific class of the error tree (hystbench/errors.py), never
the bare base: a handler can tell a wrong command-line value (ConfigError) from the rest.  main
still turns every one into one line and exit status 2."""

from __future__ import annotations

import argparse

import pytest

from hystbench.cli import main as cli_main
from hystbench.errors import ConfigError


