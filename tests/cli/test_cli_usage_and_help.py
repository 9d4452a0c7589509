"""Issue 30, items 1 and 11: a usage error is one line naming what is wrong (status 2), in every
subparser; every ``--help`` is plain text (no issue numbers, no RST double backticks)."""

from __future__ import annotations

import argparse

import pytest

from hystbench.cli.main import build_parser, main


def _all_parsers(parser: argparse.ArgumentParser):
    yield parser
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for sub in dict.fromkeys(action.choices.values()):  # aliases share one parser
                yield from _all_parsers(sub)


PARSERS = list(_all_parsers(build_parser()))
PROGS = [p.prog for p in PARSERS]


def test_the_walk_reaches_the_nested_subparsers():
    assert {"hystbench", "hystbench simulate", "hystbench ctl status", "hystbench model fit"} <= set(PROGS)


def usage_error(argv: list[str], capsys) -> str:
    code = main(argv)
    cap = capsys.readouterr()
    lines = [ln for ln in cap.err.splitlines() if ln.strip()]
    assert code == 2, cap.err
    assert len(lines) == 1, cap.err  # no usage block above it
    assert "usage:" not in cap.err and "Traceback" not in cap.err
    return lines[0]


@pytest.mark.parametrize("prog", PROGS)
def test_every_subparser_gives_a_one_line_usage_error(prog, capsys):
    line = usage_error(prog.split()[1:] + ["--no-such-option"], capsys)
    assert line.startswith(f"{prog}: error: "), line
    assert line.endswith(f"(see `{prog} --help`)"), line


def test_a_bad_value_names_its_option(capsys):
    line = usage_error(["simulate", "--freq", "x", "--ipp", "1", "--out", "o"], capsys)
    assert line.startswith("hystbench simulate: error: argument --freq:") and "'x'" in line


def test_an_unknown_command_is_named(capsys):
    line = usage_error(["simulat"], capsys)
    assert line.startswith("hystbench: error: ") and "'simulat'" in line


def test_an_unknown_option_is_named(capsys):
    line = usage_error(["rigs", "--jsn"], capsys)
    assert line.startswith("hystbench rigs: error: ") and "--jsn" in line


def test_a_missing_verb_is_named(capsys):
    line = usage_error(["ctl"], capsys)
    assert line.startswith("hystbench ctl: error: ") and "VERB" in line


@pytest.mark.parametrize("parser", PARSERS, ids=PROGS)
def test_every_help_is_plain_text(parser):
    text = parser.format_help()
    assert "``" not in text, text
    assert "issue " not in text.lower(), text
