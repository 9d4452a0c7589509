"""`hystbench ctl` / `watch` refusing what they are given, in one line (issue 26): an empty item of
``--freqs`` (``80,,160`` was two points), a ``--connect`` endpoint zenoh cannot read and a
``--zenoh-config`` file zenoh refuses, each named, without zenoh's Rust source paths."""

from __future__ import annotations

import argparse
from pathlib import Path

import pytest

from hystbench.acquisition.zenoh_bus import free_port
from hystbench.cli.args import float_list_in, positive_floats
from hystbench.cli.main import main


def run(args: list[str], capsys) -> tuple[int, str, str]:
    try:
        code = main(args)
    except SystemExit as stop:  # argparse's usage error
        code = stop.code
    cap = capsys.readouterr()
    return code, cap.out, cap.err


def nobody() -> list[str]:
    """Options that reach no daemon, at once (the old parser took ``80,,160`` and asked there)."""
    return ["--connect", f"tcp/127.0.0.1:{free_port()}", "--timeout", "0.01"]


@pytest.mark.parametrize("freqs, item", [("80,,160", 2), ("80,160,", 3), (",80", 1), ("80, ,160", 2)])
def test_an_empty_frequency_is_refused_naming_it(capsys, freqs, item):
    code, out, err = run(["ctl", *nobody(), "start_sweep", "--freqs", freqs], capsys)
    assert code == 2 and not out
    assert (f"argument --freqs: item {item} of {freqs!r} is empty; every item must be a finite number > 0"
            in err.splitlines()[-1])


def test_the_list_parsers_refuse_an_empty_item_and_take_spaces():
    assert positive_floats(" 80 , 160 ") == [80.0, 160.0]
    assert float_list_in(0, 2)("1,1.5") == [1.0, 1.5]
    for parse in (positive_floats, float_list_in(0, 2)):
        with pytest.raises(argparse.ArgumentTypeError, match=r"item 2 of '1,,1' is empty"):
            parse("1,,1")
        with pytest.raises(argparse.ArgumentTypeError, match="expected comma-separated numbers"):
            parse(" , ")


def _one_clean_line(err: str) -> str:
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert ".rs" not in err and ".cargo" not in err and "Message {" not in err and "Location" not in err, err
    return lines[0]


@pytest.mark.parametrize("command", [["ctl"], ["watch", "--count", "1", "--seconds", "0.01"]])
@pytest.mark.parametrize("endpoint", ["garbage", "tcp/", "udp"])
def test_a_bad_connect_endpoint_is_one_line_naming_it(capsys, command, endpoint):
    args = [*command, "--connect", endpoint] + (["status"] if command == ["ctl"] else [])
    code, _, err = run(args, capsys)
    assert code == 2
    line = _one_clean_line(err)
    assert f"connect endpoint {endpoint!r}: not a zenoh endpoint (<protocol>/<address>" in line, line


@pytest.mark.parametrize("endpoint", ["tcp/127.0.0.1:99999", "udp/127.0.0.1:70000?iface=lo"])
def test_a_port_no_socket_can_have_is_named_not_waited_on(capsys, endpoint):
    """zenoh takes ``tcp/127.0.0.1:99999``; the client then waited and said "no daemon answered"."""
    code, _, err = run(["ctl", "--connect", endpoint, "status"], capsys)
    line = _one_clean_line(err)
    assert code == 2 and f"connect endpoint {endpoint!r}: port " in line and "is not a TCP/UDP port (0-65535)" in line


@pytest.mark.parametrize("text, says", [
    ('{ mode: "peer", bogus: 3 }', "line 1, column 17: unknown field `bogus`, expected one of"),
    ('{ mode: "peer" ', "line 1, column 9: expected"),
    ('{ mode: "nonsense" }',
     "line 1, column 9: unknown variant `nonsense`, expected one of `router`, `peer`, `client`"),
    ('{ connect: { endpoints: ["garbage"] } }', "Endpoints must be of the form <protocol>/<address>"),
])
def test_a_bad_zenoh_config_file_is_one_line_naming_it(tmp_path: Path, capsys, text, says):
    f = tmp_path / "client.json5"
    f.write_text(text, encoding="utf-8")
    code, _, err = run(["ctl", "--zenoh-config", str(f), "status"], capsys)
    assert code == 2
    line = _one_clean_line(err)
    assert f"zenoh config {f}: " in line and says in line, line


def test_a_zenoh_config_that_is_no_file_is_named(tmp_path: Path, capsys):
    wrong = tmp_path / "client.txt"
    wrong.write_text('{ mode: "peer" }', encoding="utf-8")
    for path, says in ((wrong, f"zenoh config {wrong}: Unsupported file type '.txt'"),
                       (tmp_path, f"{tmp_path}: is a folder, not a zenoh config file"),
                       (tmp_path / "none.json5", f"{tmp_path / 'none.json5'}: zenoh config file not found")):
        code, _, err = run(["ctl", "--zenoh-config", str(path), "status"], capsys)
        assert code == 2 and says in _one_clean_line(err)


def test_arguments_over_the_cap_are_refused_before_they_are_sent():
    """The daemon refuses them (or, over MAX_MESSAGE_BYTES, zenoh drops them: no reply at all)."""
    from hystbench.service.control import BenchControl
    from hystbench.acquisition.zenoh_bus import MAX_COMMAND_BYTES
    from hystbench.errors import ConfigError

    with BenchControl("b1", connect=[f"tcp/127.0.0.1:{free_port()}"], timeout_s=0.01) as ctl:
        with pytest.raises(ConfigError, match=rf"start_sweep: the arguments are \d+ bytes of JSON, more than the "
                                              rf"{MAX_COMMAND_BYTES} a daemon takes"):
            ctl.request("start_sweep", {"frequencies_hz": [80.0] * (MAX_COMMAND_BYTES // 5)})
