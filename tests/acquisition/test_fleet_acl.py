"""Access control per bench through the router (issue 31): zenoh checks it per link, so behind a
router it is the router's to check.  A real router opened with the access control docs/fleet.md
documents (the json5 there, verbatim but for the users file), two real daemons (subprocesses,
simulated rig, sweeping) that listen nowhere and authenticate to it as their bench, and ``ctl``
clients with their own credentials: everyone may ask every bench's status; a command from a viewer,
or from one bench's operator to another bench, is dropped by the router and never reaches the daemon
(its output stays on, its ``commands_refused`` stays 0); the bench's own operator commands it; a
client without credentials gets nothing.  Every wait ends on its event; the 1-s ``--timeout`` of a
denied command is the only sign zenoh gives of a dropped query, HANG_S only turns a hang into a
failure."""

from __future__ import annotations

import json
import re
from pathlib import Path

from hystbench.acquisition.zenoh_bus import free_port, load_zenoh_config, open_session, peer_config
from hystbench.service.router import Router

from .conftest import HANG_S, ROOT, Daemon, health_when
from .test_fleet import daemon_file, run

PASSWORDS = {"bench1": "b1-secret", "bench2": "b2-secret", "alice": "alice-secret", "bob": "bob-secret",
             "viewer": "view-secret"}


def router_acl(tmp: Path) -> Path:
    """docs/fleet.md's router config, its users file a temporary one holding :data:`PASSWORDS`."""
    users = tmp / "users.txt"
    users.write_text("".join(f"{u}:{p}\n" for u, p in PASSWORDS.items()), encoding="utf-8")
    users.chmod(0o600)
    doc = (ROOT / "docs" / "fleet.md").read_text(encoding="utf-8")
    block = next(b for b in re.findall(r"```json5\n(.*?)```", doc, re.S) if "access_control" in b)
    out = tmp / "zenoh-router.json5"
    out.write_text(block.replace("/etc/hystbench/zenoh-users.txt", users.as_posix()), encoding="utf-8")
    return out


def credentials(tmp: Path, user: str, endpoint: str | None = None) -> Path:
    """A zenoh file for ``user``: a daemon's (no endpoint: the daemon file names the router) or a client's."""
    path = tmp / f"{user}.json5"
    path.write_text(json.dumps(peer_config(connect=[endpoint] if endpoint else None, user=user,
                                           password=PASSWORDS[user])), encoding="utf-8")
    return path


def test_commands_through_the_router_only_from_that_benchs_operators(tmp_path: Path, capsys) -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    with Router([endpoint], config_file=router_acl(tmp_path)):
        daemons = [Daemon(tmp_path, daemon_file(tmp_path / f"{b}.toml", b, endpoint, tmp_path / "logs",
                                                zenoh_config=credentials(tmp_path, b)), name=b)
                   for b in ("bench1", "bench2")]
        viewer = credentials(tmp_path, "viewer", endpoint)
        alice = credentials(tmp_path, "alice", endpoint)  # bench1's operator
        session = open_session(load_zenoh_config(str(viewer)))
        try:
            for d in daemons:
                d.wait_for("READY=1")
            for b in ("bench1", "bench2"):  # sweeping, output on (as played), as seen by a viewer
                health_when(session, b, lambda h: h.get("output_on") is True)
            code, out, err = run(["ctl", "--zenoh-config", str(viewer), "--bench", "*", "--timeout", str(HANG_S),
                                  "status"], capsys)
            assert code == 0, err
            assert [ln.split(":")[0] for ln in out.splitlines()] == ["bench1", "bench2"], out  # everyone may ask

            for who, bench in ((viewer, "bench1"), (alice, "bench2")):  # dropped by the router
                code, out, err = run(["ctl", "--zenoh-config", str(who), "--bench", bench, "--timeout", "1",
                                      "output", "off"], capsys)
                assert code == 2 and out == "", (who.name, bench, out, err)
                assert f"no daemon answered on hystbench/{bench}/cmd/output" in err and "access control" in err, err

            code, out, err = run(["ctl", "--zenoh-config", str(alice), "--bench", "bench1", "--timeout", str(HANG_S),
                                  "output", "off"], capsys)
            assert code == 0 and out.startswith("bench1: output ok"), (out, err)
            health_when(session, "bench1", lambda h: h.get("output_on") is False)  # alice's command, played
            # the denied ones never reached a daemon: neither refused there nor done
            h2 = health_when(session, "bench2", lambda h: True)
            assert h2["output_on"] is True and h2["commands_refused"] == 0, h2
            assert health_when(session, "bench1", lambda h: True)["commands_refused"] == 0

            anonymous = tmp_path / "anonymous.json5"  # no credentials: the router takes no traffic from it
            anonymous.write_text(json.dumps(peer_config(connect=[endpoint])), encoding="utf-8")
            code, out, err = run(["ctl", "--zenoh-config", str(anonymous), "--bench", "*", "--timeout", "1",
                                  "status"], capsys)
            assert code == 2 and out == "", (out, err)
        finally:
            session.close()
            for d in daemons:
                d.close()
