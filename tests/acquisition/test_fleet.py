"""A fleet through zenoh's own router (issue 31): a real router session on a free loopback port,
two real daemons (subprocesses, simulated rig, sweeping) that listen nowhere and connect to it;
a subscriber on the router gets the estimates of both, ``ctl --bench '*' status`` lists both,
a command to '*' is refused before anything is sent, ``watch`` sees both through the router, a
second daemon of one bench name is refused through it, a taken router port is one line naming
--listen, and a daemon whose router is not there exits 1 (systemd tries again), naming it.
Every wait ends on its event; HANG_S only turns a hang into a failure."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from hystbench.acquisition.zenoh_bus import Subscription, free_port
from hystbench.cli.main import main
from hystbench.deadline import Deadline
from hystbench.errors import ConfigError
from hystbench.service.control import bench_pattern
from hystbench.service.router import Router

from .conftest import HANG_S, ROOT, Daemon

pytestmark = pytest.mark.slow(15)  # ~15 s: handed to a worker before lighter files (tests/conftest.py)


def daemon_file(path: Path, bench: str, router: str, logs: Path, *, zenoh_config: Path | None = None) -> Path:
    """A daemon of ``bench`` on the simulated rig, sweeping at 320 Hz, a client of ``router``
    (``zenoh_config``: its zenoh file, e.g. its credentials there)."""
    zfile = f'config = "{zenoh_config.as_posix()}"\n' if zenoh_config is not None else ""
    path.write_text(f'[daemon]\nbench = "{bench}"\nlog_dir = "{logs.as_posix()}"\n[source]\nkind = "sim"\n'
                    '[recording]\nenabled = false\n'
                    f'[zenoh]\n{zfile}listen = []\nconnect = ["{router}"]\n'
                    '[sweep]\nfrequencies_hz = [320.0]\ndwell_s = 30.0\nautostart = true\n', encoding="utf-8")
    return path


def run(args: list[str], capsys) -> tuple[int, str, str]:
    code = main(args)
    cap = capsys.readouterr()
    return code, cap.out, cap.err


def test_two_daemons_through_one_router(tmp_path: Path, capsys) -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    with Router([endpoint]) as router:
        sub = Subscription(router.session, "hystbench/*/estimate")
        daemons = [Daemon(tmp_path, daemon_file(tmp_path / f"{b}.toml", b, endpoint, tmp_path / "logs"), name=b)
                   for b in ("f1", "f2")]
        try:
            for d in daemons:
                d.wait_for("READY=1")
            seen: set[str] = set()
            for key_, _payload, _t in sub.iter(seconds=HANG_S):  # ends as soon as both benches were heard
                seen.add(key_.split("/")[1])
                if seen == {"f1", "f2"}:
                    break
            assert seen == {"f1", "f2"}, f"estimates only from {seen}"

            code, out, err = run(["ctl", "--connect", endpoint, "--bench", "*", "--timeout", str(HANG_S), "status"],
                                 capsys)
            assert code == 0, err
            lines = out.splitlines()
            assert [ln.split(":")[0] for ln in lines] == ["f1", "f2"], out
            for ln in lines:
                assert "sweeping; output on at 320 Hz, 1.4 A-pp, offset 0 A" in ln and "healthy" in ln, ln

            for verb in (["output", "off"], ["start_sweep"]):
                code, out, err = run(["ctl", "--connect", endpoint, "--bench", "*", verb[0], *verb[1:]], capsys)
                assert code == 2 and out == ""
                assert err.count("\n") == 1 and "only status and health may go to several" in err, err
            # watch through the router: estimates of both benches, as on one daemon's endpoint
            # (a few runs of 8 messages: on a loaded machine one daemon's estimates may come in a burst)
            heard: set[str] = set()
            for _ in range(10):
                code, out, err = run(["watch", "--connect", endpoint, "--count", "8", "--seconds", str(HANG_S)], capsys)
                assert code == 0, err
                heard |= {ln.split("/")[1] for ln in out.splitlines()}
                if heard == {"f1", "f2"}:
                    break
            assert heard == {"f1", "f2"}, out
            # a second daemon of f1 on another "PC" (its own state folder): f1's token is seen through the router
            again = subprocess.run([sys.executable, "-m", "hystbench", "daemon", "--config", str(tmp_path / "f1.toml")],
                                   cwd=ROOT, capture_output=True, text=True, timeout=HANG_S,
                                   env={**os.environ, "STATE_DIRECTORY": str(tmp_path / "other-pc")})
            assert again.returncode == 2 and "already served on the zenoh network" in again.stderr, again.stderr
            # one bench by its name, through the same router: the command still reaches it
            code, out, err = run(["ctl", "--connect", endpoint, "--bench", "f2", "--timeout", str(HANG_S),
                                  "output", "off"], capsys)
            assert code == 0 and out.startswith("f2: output ok"), err
        finally:
            sub.close()
            for d in daemons:
                d.close()


def test_a_taken_router_port_names_listen(capsys) -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    with Router([endpoint]):
        code, out, err = run(["router", "--listen", endpoint], capsys)
    assert code == 2 and out == ""
    assert err.count("\n") == 1 and f"cannot listen on {endpoint}" in err and "--listen" in err, err


def test_a_daemon_whose_router_is_not_there_exits_1_naming_it(tmp_path: Path) -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"  # nobody listens there
    cfg = daemon_file(tmp_path / "d.toml", "f3", endpoint, tmp_path / "logs")
    proc = subprocess.run([sys.executable, "-m", "hystbench", "daemon", "--config", str(cfg)], cwd=ROOT,
                          capture_output=True, text=True, timeout=HANG_S,
                          env={**os.environ, "STATE_DIRECTORY": str(tmp_path / "state")})
    assert proc.returncode == 1, proc.stderr
    assert f"[zenoh] connect: cannot reach {endpoint}" in proc.stderr and "hystbench router" in proc.stderr


def test_the_router_runs_until_sigterm_and_says_where_it_listens() -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    proc = subprocess.Popen([sys.executable, "-m", "hystbench", "router", "--listen", endpoint], cwd=ROOT,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        line = proc.stdout.readline()  # the first line: printed once it listens
        assert f"listening on {endpoint}" in line, (line, proc.stderr.read() if proc.poll() is not None else "")
        proc.terminate()
        assert proc.wait(timeout=Deadline(HANG_S).left()) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


#: ``hystbench router`` whose session never finishes closing (a make test run once saw a router's
#: shutdown hang past 60 s after a Foxglove client had come and gone)
HUNG_CLOSE = """
import sys, threading
import hystbench.service.router as router
router.Router.close = lambda self: threading.Event().wait()
from hystbench.cli.main import main
sys.exit(main(sys.argv[1:]))
"""


def test_a_router_whose_shutdown_hangs_ends_within_its_bound_saying_so() -> None:
    from hystbench.cli.router import STOP_S

    endpoint = f"tcp/127.0.0.1:{free_port()}"
    proc = subprocess.Popen([sys.executable, "-c", HUNG_CLOSE, "router", "--listen", endpoint], cwd=ROOT,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert f"listening on {endpoint}" in proc.stdout.readline()
        proc.terminate()
        assert proc.wait(timeout=HANG_S) == 1
        assert f"SIGTERM: the router did not stop within {STOP_S:g} s; exiting now" in proc.stderr.read()
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


def test_a_bench_pattern_is_one_key_chunk() -> None:
    assert bench_pattern("*") == "*"
    assert bench_pattern("lab-*") == "lab-$*"
    for bad in ("a/b", "lab$", "x?", ""):
        with pytest.raises(ConfigError, match="bench pattern"):
            bench_pattern(bad)
