"""What a client sends on ``cmd/<verb>`` before the bench sees it (issue 26): a payload over
``MAX_COMMAND_BYTES`` is refused unparsed, one nested too deep is refused without the parser's
recursion (and without a traceback in the log), a parse error names the verb, and every refused
command is exactly one log line naming the verb and the reason.  The sessions the bench opens
take no peer's shared memory (a peer's 16 MiB segment stayed mapped for good), and a serving
one reassembles at most ``MAX_MESSAGE_BYTES`` per message.

A ZenohBus and a client session on a loopback endpoint; the command handler is a stub that
accepts whatever reaches it, so a refusal here is the bus's own."""

from __future__ import annotations

import json
import logging

import pytest

from hystbench.acquisition.zenoh_bus import (MAX_COMMAND_BYTES, MAX_COMMAND_DEPTH, MAX_MESSAGE_BYTES, ZenohBus,
                                             free_port, key, load_zenoh_config, open_session, peer_config)
from hystbench.log_budget import LogBudget

HANG_S = 30.0  # a reply's timeout: it only turns a hang into a failure


@pytest.fixture
def bus():
    """A bus 'p' on a loopback port whose commands reach a stub (which records them), and a
    client session connected to it."""
    port = free_port()
    seen: list[tuple[str, dict]] = []

    def on_command(verb: str, args: dict) -> dict:
        seen.append((verb, args))
        return {"took": sorted(args)}

    b = ZenohBus("p", load_zenoh_config(None, listen=[f"tcp/127.0.0.1:{port}"]), on_command=on_command).open()
    client = open_session(load_zenoh_config(peer_config(connect=[f"tcp/127.0.0.1:{port}"])))
    try:
        yield client, seen, b
    finally:
        client.close()
        b.close()


def ask(client, verb: str, payload: bytes) -> dict:
    """The one reply to ``cmd/<verb>`` with ``payload``, decoded, with ``ok`` as the reply's kind."""
    for _ in range(int(HANG_S)):  # a fresh client may not see the queryable yet: asked again
        replies = list(client.get(key("p", "cmd", verb), payload=payload, timeout=HANG_S))
        if replies and not (replies[0].err is not None and replies[0].err.payload.to_bytes() == b"Timeout"):
            break
    assert len(replies) == 1, replies
    r = replies[0]
    body = json.loads((r.ok or r.err).payload.to_bytes())
    assert body["ok"] is (r.ok is not None)
    return body


def zenoh_records(caplog) -> list[logging.LogRecord]:
    return [r for r in caplog.records if r.name == "hystbench.zenoh"]


def test_a_payload_over_the_cap_is_refused_unparsed_and_one_at_the_cap_is_taken(bus, caplog):
    client, seen, _ = bus
    pad = MAX_COMMAND_BYTES - len(json.dumps({"on": True, "pad": ""}))
    at_cap = json.dumps({"on": True, "pad": "x" * pad}).encode()
    assert len(at_cap) == MAX_COMMAND_BYTES
    assert ask(client, "output", at_cap)["ok"]
    assert seen == [("output", {"on": True, "pad": "x" * pad})]
    caplog.clear()
    with caplog.at_level(logging.INFO, logger="hystbench.zenoh"):
        reply = ask(client, "output", at_cap[:-1] + b' }')  # one byte more, still a JSON object
    assert reply["error"] == (f"cmd/output: the payload is {MAX_COMMAND_BYTES + 1} bytes, more than the "
                              f"{MAX_COMMAND_BYTES} a command may have")
    assert len(seen) == 1  # never reached the bench
    (rec,) = zenoh_records(caplog)
    assert rec.getMessage() == f"cmd/output refused: {reply['error']}" and rec.exc_info is None


@pytest.mark.parametrize("payload, depth", [
    (b"[" * 30_000, 30_000),  # the parser's recursion: a RecursionError and its traceback before
    (b'{"frequencies_hz": ' + b"[" * (MAX_COMMAND_DEPTH) + b"1" + b"]" * MAX_COMMAND_DEPTH + b"}",
     MAX_COMMAND_DEPTH + 1),
])
def test_too_deep_a_payload_is_refused_in_one_line_without_a_traceback(bus, caplog, payload, depth):
    client, seen, _ = bus
    with caplog.at_level(logging.INFO, logger="hystbench.zenoh"):
        replies = [ask(client, "start_sweep", payload) for _ in range(5)]
    assert {r["error"] for r in replies} == {f"cmd/start_sweep: the payload nests arrays and objects {depth} deep, "
                                             f"more than the {MAX_COMMAND_DEPTH} a command may have"}
    assert not seen
    records = zenoh_records(caplog)
    assert len(records) == 5 and all(r.exc_info is None and r.levelno == logging.WARNING for r in records)
    assert all(r.getMessage().startswith("cmd/start_sweep refused: ") for r in records)


def test_brackets_inside_strings_are_no_nesting(bus):
    client, seen, _ = bus
    assert ask(client, "output", json.dumps({"on": False, "note": "[" * 100 + "{" * 100}).encode())["ok"]
    assert ask(client, "start_sweep", json.dumps({"frequencies_hz": [80.0, 160.0]}).encode())["ok"]
    assert len(seen) == 2


@pytest.mark.parametrize("payload, why", [
    (b'{"on": tru', "Expecting value: line 1 column 8 (char 7)"),
    (b"{\xff}", "can't decode byte 0xff"),
    (b'{"on": ' + b"1" * 5000 + b"}", "Exceeds the limit (4300 digits) for integer string conversion"),
])
def test_a_payload_that_is_not_json_is_refused_naming_the_verb(bus, caplog, payload, why):
    client, seen, _ = bus
    with caplog.at_level(logging.INFO, logger="hystbench.zenoh"):
        reply = ask(client, "output", payload)
    assert reply["error"].startswith("cmd/output: the payload is not JSON: ") and why in reply["error"]
    assert not seen
    (rec,) = zenoh_records(caplog)
    assert rec.getMessage() == f"cmd/output refused: {reply['error']}"


def test_every_refused_command_is_one_log_line_naming_the_verb_and_why(bus, caplog):
    """Refused by the bus (unknown verb, too big, not an object) and by the bench (its handler
    raising ConfigError or CommandRefused): one WARNING each, on one line, none for an accepted one."""
    from hystbench.errors import CommandRefused, ConfigError

    client, seen, b = bus

    def on_command(verb: str, args: dict) -> dict:
        if "bad" in args:
            raise ConfigError(f"{verb}: unknown argument(s) ['bad']")
        if verb == "start_sweep":
            raise CommandRefused("start_sweep: a sweep is running;\nstop_sweep first")  # a newline: still one line
        return {}

    b.on_command = on_command
    cases = [("self_destruct", b"{}", "'self_destruct'", "unknown command 'self_destruct'"),
             ("x\nFAKE LINE", b"{}", "'x\\nFAKE LINE'", "unknown command 'x\\nFAKE LINE'"),
             ("output", b"[1, 2]", "output", "must be a JSON object, got list"),
             ("output", b'{"bad": 1}', "output", "unknown argument(s) ['bad']"),
             ("start_sweep", b"{}", "start_sweep", "a sweep is running;\\nstop_sweep first"),
             ("output", b"x" * (MAX_COMMAND_BYTES + 1), "output", "more than the")]
    with caplog.at_level(logging.INFO, logger="hystbench.zenoh"):
        assert ask(client, "output", b'{"on": true}')["ok"]  # accepted: no line
        for verb, payload, _, _ in cases:
            assert not ask(client, verb, payload)["ok"]
    records = zenoh_records(caplog)
    assert len(records) == len(cases) and b.refused == len(cases)
    for rec, (_, _, shown, why) in zip(records, cases):
        line = rec.getMessage()
        assert line.startswith(f"cmd/{shown} refused: ") and why in line, line
        assert "\n" not in line and rec.exc_info is None


def test_a_failing_handler_logs_its_traceback_once_then_one_line_each(bus, caplog):
    client, _, b = bus

    def on_command(verb: str, args: dict) -> dict:
        raise ZeroDivisionError("a bug")

    b.on_command = on_command
    with caplog.at_level(logging.INFO, logger="hystbench.zenoh"):
        replies = [ask(client, "output", b'{"on": true}') for _ in range(4)]
    assert {r["error"] for r in replies} == {"cmd/output failed: ZeroDivisionError: a bug"}
    records = zenoh_records(caplog)
    assert len(records) == 4 and [bool(r.exc_info) for r in records] == [True, False, False, False]
    assert all(r.getMessage().startswith("cmd/output failed: ZeroDivisionError: a bug") for r in records)


def test_a_flood_of_refused_commands_is_counted_not_logged_line_by_line(bus, caplog):
    """A client repeating a refused command wrote one line each (20 000 commands, 19 887 lines): past
    the budget the rest are counted, and the count is one line, when the daemon's loop asks for it
    (every turn) or when the next window opens; every one is in ``refused``.  The budget's clock is
    the test's, so the windows are the test's choice."""
    client, _, b = bus
    now = [0.0]
    b.refusal_log = LogBudget(3, 1.0, clock=lambda: now[0])
    held = "{} more commands refused, not logged one by one (health's commands_refused counts every one)"
    with caplog.at_level(logging.INFO, logger="hystbench.zenoh"):
        for _ in range(7):
            assert not ask(client, "self_destruct", b"{}")["ok"]
        lines = [r.getMessage() for r in zenoh_records(caplog)]
        assert len(lines) == 3 and all(ln.startswith("cmd/'self_destruct' refused: ") for ln in lines)
        assert "refusals beyond 3 a second are counted, not logged" in lines[-1]
        b.report_held_refusals()  # the daemon's loop, every turn
        for _ in range(2):
            assert not ask(client, "self_destruct", b"{}")["ok"]
        now[0] = 1.0  # the next window: the two held back since are said first
        assert not ask(client, "output", b"[1]")["ok"]
        b.close()
    lines = [r.getMessage() for r in zenoh_records(caplog)]
    assert lines[3:] == [held.format(4), held.format(2),
                         "cmd/output refused: cmd/output: the payload must be a JSON object, got list"], lines
    assert b.refused == 10


def _get(cfg, path: str):
    return json.loads(cfg.get_json(path))


def test_no_session_takes_shared_memory_and_a_serving_one_caps_its_messages(tmp_path):
    """A peer's shared-memory segment (16 MiB each client session) stayed mapped in the daemon for
    good; off in every session hystbench opens, a file that turns it on included."""
    f = tmp_path / "z.json5"
    f.write_text('{ mode: "peer", listen: { endpoints: ["tcp/127.0.0.1:0"] },\n'
                 '  transport: { shared_memory: { enabled: true }, link: { rx: { max_message_size: 512 } } } }',
                 encoding="utf-8")
    serving = [load_zenoh_config(None, listen=["tcp/127.0.0.1:0"]), load_zenoh_config(f),
               load_zenoh_config(None, connect=["tcp/127.0.0.1:1"], serve=True)]
    clients = [load_zenoh_config(None, connect=["tcp/127.0.0.1:1"]), load_zenoh_config(peer_config()),
               load_zenoh_config(f, listen=[], serve=False)]
    for cfg in serving + clients:
        assert _get(cfg, "transport/shared_memory/enabled") is False
    assert [_get(c, "transport/link/rx/max_message_size") for c in serving] == [MAX_MESSAGE_BYTES, 512,
                                                                                 MAX_MESSAGE_BYTES]
    assert {_get(c, "transport/link/rx/max_message_size") for c in clients[:2]} == {2**30}  # zenoh's own
    assert MAX_COMMAND_BYTES < MAX_MESSAGE_BYTES  # a payload a little over the cap is refused with a reason
