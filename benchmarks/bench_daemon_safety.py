"""The daemon under the commands and disks that used to stop it (issue 26): the figures the closing note quotes.

- ``sweep_offset``: a sweep at 1.4 A-pp, then ``set_excitation`` 0.2 A-pp + 1.2 A offset during its
  first point (the emulated bench, amplifier trip at 1.8 A): the peak coil current in the log, and
  whether the amplifier tripped;
- ``at_limit``: six cycles of a DC offset at the command limit + ``output on`` (and the refusal of one
  at the 1.8 A trip level itself): faults and trips counted, the peak current;
- ``flood_off``: 20 000 ``set_excitation`` as fast as a client sends them with the output on, then
  ``output off``: how many were taken and refused as busy, and seconds until the emulated generator
  and amplifier were off;
- ``full_disk`` (root: a tmpfs): a daemon process whose log fills a 16 MiB disk: seconds from the
  ``log_write_failed`` status to the first raw block with the output off, as a zenoh subscriber
  receives them, seconds to resume
  once room is back, and seconds from SIGTERM to exit, paused and running.

Run: ``python -m benchmarks daemon_safety [--cases sweep_offset,at_limit,flood_off,full_disk]``; one JSON line per case.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

HANG_S = 60.0


def _service(tmp: Path, bench: str):
    from hystbench.service.daemon_config import load_daemon_config
    from hystbench.service.service import BenchService

    toml = tmp / "daemon.toml"
    toml.write_text(f'[daemon]\nbench = "{bench}"\nlog_dir = "{tmp.as_posix()}"\n[source]\nkind = "bench"\n'
                    '[recording]\nidle_raw = "full"\n[zenoh]\nenabled = false\n[estimation]\nenabled = false\n'
                    '[sweep]\ndwell_s = 3.0\n', encoding="utf-8")
    return BenchService(load_daemon_config(toml)).start()


def _peak(paths) -> float:
    from hystbench.formats.mcaplog import iter_blocks

    return max(float(np.max(np.abs(b.channels["current_A"]))) for p in paths for b in iter_blocks(p) if b.n)


def _on_event(svc, name: str) -> threading.Event:
    ev = threading.Event()
    svc.pipeline.listeners.append(lambda t, o: ev.set() if t == "/status" and o["event"] == name else None)
    return ev


def sweep_offset() -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        svc = _service(Path(tmp), "sweep")
        point, stopped = _on_event(svc, "sweep_point"), _on_event(svc, "sweep_stopped")
        try:
            svc.command("start_sweep", {"frequencies_hz": [80.0, 160.0, 320.0], "current_pp_a": 1.4})
            point.wait(HANG_S)
            svc.command("set_excitation", {"current_pp_a": 0.2, "offset_a": 1.2})
            stopped.wait(HANG_S)
            trips, faults = svc.trips, len(svc.faults)
        finally:
            paths = svc.stop()
        return {"case": "sweep_offset", "peak_current_a": round(_peak(paths), 4), "trip_level_a": 1.8,
                "command_limit_a": svc.limits.max_current_a, "sweep_stopped": stopped.is_set(), "trips": trips,
                "faults": faults}


def at_limit() -> dict:
    from hystbench.errors import ConfigError

    with tempfile.TemporaryDirectory() as tmp:
        svc = _service(Path(tmp), "limit")
        refused = 0
        try:
            try:
                svc.command("set_excitation", {"current_pp_a": 0.0, "offset_a": 1.8})
            except ConfigError:
                refused += 1
            for _ in range(6):
                svc.command("set_excitation", {"current_pp_a": 0.0, "offset_a": svc.limits.max_current_a})
                svc.command("output", {"on": True})
                svc.pipeline.after_samples(50_000).wait(HANG_S)
                svc.command("output", {"on": False})
                svc.recover()
            state, trips, faults = svc.state, svc.trips, len(svc.faults)
        finally:
            paths = svc.stop()
        return {"case": "at_limit", "cycles": 6, "refused_at_1.8_a": refused, "state": state, "trips": trips,
                "faults": faults, "peak_current_a": round(_peak(paths), 4)}


def flood_off(n: int = 20_000) -> dict:
    """``n`` set_excitation as fast as one client thread sends them to the emulated bench's service
    with the output on, then ``output off``: how many were taken and refused as busy, and how long the
    off took until the emulated generator and amplifier were off (the off used to wait behind every
    queued command: 10 s after 20 000)."""
    from hystbench.errors import CommandRefused

    with tempfile.TemporaryDirectory() as tmp:
        svc = _service(Path(tmp), "flood")
        emu = svc.source.emu
        try:
            svc.command("output", {"on": True})
            t0 = time.monotonic()
            while not emu.generator.state["output"] and time.monotonic() - t0 < HANG_S:
                time.sleep(0.01)
            taken = refused = 0
            t0 = time.monotonic()
            for k in range(n):
                try:
                    svc.command("set_excitation", {"current_pp_a": 1.0 + 0.5 * (k % 2)})
                    taken += 1
                except CommandRefused:
                    refused += 1
            flood_s = time.monotonic() - t0
            t0 = time.monotonic()
            svc.command("output", {"on": False})
            while (emu.generator.state["output"] or emu.amplifier.enabled) and time.monotonic() - t0 < HANG_S:
                time.sleep(0.001)
            off_s = time.monotonic() - t0
            off = not (emu.generator.state["output"] or emu.amplifier.enabled)
        finally:
            svc.stop()
        return {"case": "flood_off", "commands": n, "taken": taken, "refused_busy": refused,
                "flood_s": round(flood_s, 2), "off_after_s": round(off_s, 4), "off": off}


def _health(session, bench: str, cond) -> dict:
    from hystbench.acquisition.zenoh_bus import query_json

    t0 = time.monotonic()
    while time.monotonic() - t0 < HANG_S:
        got = query_json(session, f"hystbench/{bench}/health", timeout_s=1.0)
        if got and cond(got[0]):
            return got[0]
    raise RuntimeError(f"{bench}: health never met the condition")


def full_disk() -> dict:
    from hystbench.acquisition.zenoh_bus import (Subscription, free_port, load_zenoh_config, open_session,
                                                 peer_config, send_command)
    from hystbench.formats.raw_block import decode
    from hystbench.messages import OperatingPoint

    tmp = Path(tempfile.mkdtemp())
    disk = tmp / "disk"
    disk.mkdir()
    if subprocess.run(["mount", "-t", "tmpfs", "-o", "size=16m", "tmpfs", str(disk)], capture_output=True).returncode:
        return {"case": "full_disk", "skipped": "mount -t tmpfs needs root"}
    proc = session = None
    try:
        port, cfg = free_port(), tmp / "daemon.toml"
        cfg.write_text(f'[daemon]\nbench = "disk"\nlog_dir = "{disk}/logs"\n[source]\nkind = "sim"\n'
                       '[recording]\nidle_raw = "full"\nflush_interval_s = 0.25\nmax_total_gib = 0.0\n'
                       f'[zenoh]\nlisten = ["tcp/127.0.0.1:{port}"]\n', encoding="utf-8")
        filler = disk / "filler.bin"
        with open(filler, "wb") as fh:
            fh.write(b"\0" * (shutil.disk_usage(disk).free - 3 * 2**20))
        env = dict(os.environ, STATE_DIRECTORY=str(tmp / "state"))
        proc = subprocess.Popen([sys.executable, "-m", "hystbench", "daemon", "--config", str(cfg)], env=env,
                                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        session = open_session(load_zenoh_config(peer_config(connect=[f"tcp/127.0.0.1:{port}"])))
        status, raw = Subscription(session, "hystbench/disk/status"), Subscription(session, "hystbench/disk/raw")
        _health(session, "disk", lambda h: h["state"] == "running")
        send_command(session, "disk", "output", {"on": True}, timeout_s=30.0)
        failed_ns = None  # when each came to this subscriber (monotonic): the failure, then the output off
        while failed_ns is None:
            got = status.get(HANG_S)
            failed_ns = got[2] if json.loads(got[1])["event"] == "log_write_failed" else None
        while True:
            got = raw.get(HANG_S)
            if got[2] > failed_ns and not OperatingPoint.from_meta(decode(got[1]).meta).output_on:
                off_ns = got[2]
                break
        _health(session, "disk", lambda h: h["logging"] == "paused")
        filler.unlink()
        t0 = time.monotonic()
        _health(session, "disk", lambda h: h["logging"] == "on")
        resumed_s = time.monotonic() - t0
        send_command(session, "disk", "output", {"on": True}, timeout_s=30.0)
        t0 = time.monotonic()
        proc.send_signal(signal.SIGTERM)
        code = proc.wait(timeout=HANG_S)
        return {"case": "full_disk", "enospc_to_output_off_s": round((off_ns - failed_ns) / 1e9, 3),
                "room_to_resumed_s": round(resumed_s, 2), "sigterm_to_exit_s": round(time.monotonic() - t0, 2),
                "exit": code}
    finally:
        if session is not None:
            session.close()
        if proc is not None and proc.poll() is None:
            proc.kill()
        subprocess.run(["umount", "-l", str(disk)], check=False)
        shutil.rmtree(tmp, ignore_errors=True)


CASES = {"sweep_offset": sweep_offset, "at_limit": at_limit, "flood_off": flood_off, "full_disk": full_disk}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", default=",".join(CASES))
    args = ap.parse_args(argv)
    for name in args.cases.split(","):
        print(json.dumps(CASES[name]()), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
