"""What the command line refuses is a specific class of the error tree (hystbench/errors.py), never
the bare base: a handler can tell a wrong command-line value (ConfigError) from the rest.  main
still turns every one into one line and exit status 2."""

from __future__ import annotations

import argparse

import pytest

from hystbench.cli import main as cli_main
from hystbench.errors import ConfigError


def test_an_unknown_benchmark_name_is_a_config_error(capsys) -> None:
    with pytest.raises(ConfigError, match="no benchmark 'no_such'; known: "):
        cli_main.cmd_bench(argparse.Namespace(name="no_such", rest=[]))
    assert cli_main.main(["bench", "no_such"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("hystbench bench: error: no benchmark 'no_such'") and "\n" not in err
