"""Issue 26 items 1 and 2: no command the daemon accepts can trip the amplifier, and a trip the
excitation caused never adds up to stopping the service.

The bench is the shipped one with emulated instruments: its amplifier trips (OVERCURRENT) when
any sample of the coil current it measures exceeds its ``current_limit_a`` of 1.8 A, as a real
one does.  Commands are checked against the command limit, 1.8 A less the 5 % margin."""

from __future__ import annotations

import threading
from pathlib import Path

import numpy as np
import pytest

from hystbench.acquisition.sources import RigSource
from hystbench.drivers.safety import DEFAULT_MARGIN, CurrentBudget, SafetyLimitError
from hystbench.errors import CommandRefused, ConfigError
from hystbench.formats.mcaplog import iter_blocks
from hystbench.service.daemon_config import load_daemon_config
from hystbench.service.service import BenchService
from hystbench.service.service import MAX_FAULTS
from hystbench.sim_backend.rig import SimulatedRig

HANG_S = 60.0  # waits end on their event; only a hang takes this long
TRIP_A = 1.8  # the shipped bench file's amplifier current_limit_a
COMMAND_LIMIT_A = TRIP_A * (1 - 0.05)  # less the shipped [bench] current_margin


def bench_service(tmp: Path, bench: str, dwell_s: float = 3.0) -> BenchService:
    toml = tmp / "daemon.toml"
    toml.write_text(f'[daemon]\nbench = "{bench}"\nlog_dir = "{tmp.as_posix()}"\n[source]\nkind = "bench"\n'
                    f'[recording]\nidle_raw = "full"\n[zenoh]\nenabled = false\n'
                    f'[estimation]\nenabled = false\n[sweep]\ndwell_s = {dwell_s}\n', encoding="utf-8")
    return BenchService(load_daemon_config(toml)).start()


def statuses(svc: BenchService) -> tuple[dict[str, threading.Event], list[dict]]:
    """Events set when a status of each event name was published, and every status, in order."""
    seen: dict[str, threading.Event] = {}
    out: list[dict] = []

    def on(topic: str, obj: dict) -> None:
        if topic == "/status":
            out.append(obj)
            seen.setdefault(obj["event"], threading.Event()).set()
    svc.pipeline.listeners.append(on)
    return seen, out


def wait_event(seen: dict[str, threading.Event], name: str) -> None:
    ev = seen.setdefault(name, threading.Event())
    assert ev.wait(HANG_S), f"no {name!r} status"


def peak_current(paths: list[Path]) -> float:
    return max(float(np.max(np.abs(b.channels["current_A"]))) for p in paths for b in iter_blocks(p) if b.n)


def test_the_command_limit_is_the_trip_level_less_the_margin(tmp_path: Path) -> None:
    svc = bench_service(tmp_path, "lim")
    try:
        assert svc.limits.max_current_a == pytest.approx(COMMAND_LIMIT_A)
        assert svc.source.bench.budget.command_limit_a == pytest.approx(COMMAND_LIMIT_A)
        with pytest.raises(ConfigError, match="exceeds the bench's limit of 1.71 A"):
            svc.command("set_excitation", {"current_pp_a": 0.0, "offset_a": TRIP_A})  # at the trip level itself
    finally:
        svc.stop()


def test_an_offset_set_during_a_sweep_stops_the_sweep_before_a_point_it_would_push_past_the_limit(
        tmp_path: Path) -> None:
    """The issue's case: a sweep at 1.4 A-pp, then set_excitation 0.2 A-pp + 1.2 A offset (peak
    1.3 A, accepted).  The sweep's next point, 1.4 A-pp with that offset, peaks at 1.9 A: it is
    refused when applied, the output goes off, and the amplifier never trips."""
    svc = bench_service(tmp_path, "sw")
    seen, said = statuses(svc)
    try:
        svc.command("start_sweep", {"frequencies_hz": [80.0, 160.0, 320.0], "current_pp_a": 1.4})
        wait_event(seen, "sweep_point")  # point 0 is playing (for 3 s of the bench's clock)
        assert svc.command("set_excitation", {"current_pp_a": 0.2, "offset_a": 1.2})["applied"]
        wait_event(seen, "sweep_stopped")
        stopped = [s for s in said if s["event"] == "sweep_stopped"][0]
        assert stopped["level"] == "error" and "1.9 A exceeds the bench's limit of 1.71 A" in stopped["message"]
        assert stopped["point"] == 1 and "output off" in stopped["message"]
        assert svc.pipeline.error is None and not svc.faults and svc.trips == 0
        assert not [s for s in said if s["event"] == "sweep_point" and s["point"] > 0]
    finally:
        paths = svc.stop()
    assert 0.65 < peak_current(paths) < COMMAND_LIMIT_A * 1.01  # 1.4 A-pp and then 1.3 A were driven; never more


def test_excitation_at_the_command_limit_runs_without_a_trip(tmp_path: Path) -> None:
    """The issue's second case, at the limit the daemon now takes: a DC offset exactly at the
    command limit, switched on; the amplifier's noisy monitor stays under its trip level."""
    svc = bench_service(tmp_path, "dc")
    try:
        svc.command("set_excitation", {"current_pp_a": 0.0, "offset_a": COMMAND_LIMIT_A})
        svc.command("output", {"on": True})
        assert svc.pipeline.after_samples(round(1.0 * svc.source.fs_hz)).wait(HANG_S)  # a second of samples
        assert svc.pipeline.error is None and svc.trips == 0 and not svc.faults
    finally:
        paths = svc.stop()
    assert COMMAND_LIMIT_A * 0.99 < peak_current(paths) < TRIP_A


def test_trips_never_add_up_to_stopping_the_service_and_refuse_output_on_until_cleared(tmp_path: Path) -> None:
    """More OVERCURRENT trips than MAX_FAULTS, each met by a restart: none counts towards giving
    up; 'output on' is refused, saying why and how to clear it, until clear_fault."""
    svc = bench_service(tmp_path, "trip")
    try:
        for k in range(MAX_FAULTS + 2):
            svc.source.emu.amplifier.trip("OVERCURRENT")  # as the amplifier latches it on too much current
            assert svc.pipeline.join(HANG_S)
            assert svc.recover(), f"trip {k}"
            assert svc.state == "running"
            with pytest.raises(CommandRefused, match="tripped the bench .*OVERCURRENT.* send clear_fault"):
                svc.command("output", {"on": True})
            with pytest.raises(CommandRefused, match="clear_fault"):
                svc.command("start_sweep", {})
        health = svc.health()
        assert health["trips"] == MAX_FAULTS + 2 and health["faults"] == 0 and "OVERCURRENT" in health["output_refused"]
        assert "OVERCURRENT" in svc.command("clear_fault", {})["cleared"]
        assert svc.command("output", {"on": True}) == {"output_on": True}
        assert svc.health()["output_refused"] is None
    finally:
        svc.stop()


@pytest.mark.parametrize("ipp, offset", [(2 * COMMAND_LIMIT_A, 0.0), (0.0, COMMAND_LIMIT_A),
                                          (COMMAND_LIMIT_A, COMMAND_LIMIT_A / 2)])
def test_the_margin_covers_what_the_emulated_amplifier_adds_to_the_commanded_peak(ipp: float, offset: float) -> None:
    """The rig's current channel with the amplifier's distortion, the monitor's noise and the ADC:
    its peak over 2 s exceeds the commanded one by less than the margin (0.7 % measured)."""
    rig = SimulatedRig("voicecoil_ferrite", fs_hz=100_000.0, seed=3, frequency_hz=320.0, current_pp_a=ipp,
                       effects={"amplifier_distortion": True, "sensor_noise": True, "adc_quantisation": True})
    rig.set_excitation(320.0, ipp, offset)
    rig.output_enabled = True
    peak = float(np.max(np.abs(rig.read(200_000).channels["current_A"])))
    assert COMMAND_LIMIT_A < peak < COMMAND_LIMIT_A * (1 + DEFAULT_MARGIN) < TRIP_A * (1 + 1e-12)


# --- the drivers' budget: the last check, where the command is applied -----------------------------
def test_the_budget_bounds_commands_by_the_trip_level_less_the_margin() -> None:
    b = CurrentBudget(2.0, 0.5, margin=0.05)
    assert b.command_limit_a == pytest.approx(1.9)  # no trip level known: max_current_a less 5 %
    b.commit_limit(1.8)
    assert b.command_limit_a == pytest.approx(1.71)
    b.check_command("gen", "ok", 1.71 / 0.5)  # 3.42 V x 0.5 A/V: at the limit
    with pytest.raises(SafetyLimitError, match="1.72 A exceeds the command limit 1.71 A .*amplifier trip 1.8 A"):
        b.check_command("gen", "over", 1.72 / 0.5)
    b.commit_command(1.7 / 0.5)
    with pytest.raises(SafetyLimitError, match="lower the excitation first"):
        b.check_limit("amp", "current_limit = 1.75 A", 1.75)  # 1.7 A playing would be within 5 % of a 1.75 A trip
    b.check_limit("amp", "current_limit = 1.8 A", 1.8)
    with pytest.raises(SafetyLimitError, match="exceeds max_current_a"):
        b.check_limit("amp", "current_limit = 2.1 A", 2.1)


# --- the current a command really drives (the simulated rig's physics, checked before it is applied) ---

def test_a_flux_fed_toroid_is_refused_the_current_its_eddy_field_draws_at_10_khz():
    """The toroid runs in flux feedback: 2.4 A-pp of command is B = 1.2 T, and the current is what the
    iron needs, i = H l / N.  At 10 kHz the lamination's eddy field alone, sigma d^2/12 dB/dt, needs
    2.2e6 S/m x (0.5 mm)^2 / 12 x 1.2 T x 2 pi 10 kHz = 3456 A/m, 7.06 A through 100 turns on a 204 mm
    path: far beyond the 1.71 A limit that the nominal 1.2 A passed (the coil drew 7.1 A)."""
    import math

    rig = SimulatedRig("toroid", frequency_hz=40.0, current_pp_a=0.8)
    rig.output_enabled = False
    src = RigSource(rig, block_samples=100, pace="max", max_current_a=1.71)
    eddy_h = 2.2e6 * 0.5e-3**2 / 12 * 1.2 * 2 * math.pi * 1e4
    eddy_i = eddy_h * math.pi * (25e-3 + 40e-3) / 100
    assert 7.0 < eddy_i < 7.1
    peak = rig.peak_current_a(1e4, 2.4, 0.0)
    assert eddy_i <= peak <= 1.1 * eddy_i  # at B = 0, where dB/dt peaks, the static field adds only its coercivity
    with pytest.raises(ConfigError, match=r"really drives peaks at 7\.\d+ A, beyond the bench's max_current_a = 1\.71 A"):
        src.set_excitation(frequency_hz=1e4, current_pp_a=2.4)
    src.set_excitation(frequency_hz=40.0, current_pp_a=2.4)  # 1.2 T at 40 Hz: the loop's own field, well inside
    src.close()


def test_an_amplifier_distortion_is_in_the_current_checked():
    """i = i0 + k2 i0^2 + k3 i0^3 with k2 = k3 = 0.1 /A, /A^2: a command of 1.5 A peak drives
    1.5 + 0.225 + 0.3375 = 2.06 A, beyond 1.71 A (it tripped the emulated amplifier); 1.2 A peak
    drives 1.2 + 0.144 + 0.1728 = 1.52 A and is accepted."""
    rig = SimulatedRig("ecore", effects={"amplifier_distortion": {"second": 0.1, "third": 0.1}})
    rig.output_enabled = False
    src = RigSource(rig, block_samples=100, pace="max", max_current_a=1.71)
    assert rig.peak_current_a(current_pp_a=3.0, offset_a=0.0) == pytest.approx(2.0625, rel=1e-6)
    with pytest.raises(ConfigError, match=r"peaks at 2\.06\d* A"):
        src.set_excitation(current_pp_a=3.0, offset_a=0.0)
    src.set_excitation(current_pp_a=2.4, offset_a=0.0)
    src.close()
