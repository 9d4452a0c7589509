"""The emulated bench's only time is its sample clock: the pacing policy (never ahead of real time,
never a burst after falling behind), the amplifier's watchdog counted in samples, and stream faults
placed at a sample index.  Everything here runs on sample indices and injected times: no sleeps."""

import struct

import numpy as np
import pytest

from hystbench.blocks import SampleBlock
from hystbench.drivers.protocols import modbus_map as mb
from hystbench.drivers.protocols.framing import FrameError, decode_frame
from hystbench.sim_backend.emulators.bench import Pacer
from hystbench.sim_backend.emulators.common import Faults, FrameEmitter
from hystbench.sim_backend.emulators.current_amplifier import CurrentAmplifierEmulator

FS = 100_000.0
BLOCK = 1000


def test_pacer_keeps_real_time_and_does_not_burst_after_a_stall():
    p = Pacer(FS, start_s=0.0, start_index=0, catch_up_s=0.02)
    assert p.wait_s(BLOCK, now_s=0.002) == pytest.approx(0.008)  # early: wait for the block's time
    assert p.wait_s(2 * BLOCK, now_s=0.025) == 0.0  # 5 ms late: caught up at once
    assert p.slipped_s == 0.0
    # the machine stalls the clock for 1 s: it goes on from there at the sample rate ...
    assert p.wait_s(3 * BLOCK, now_s=1.0) == 0.0
    assert p.late_s == pytest.approx(0.97) and p.slipped_s == pytest.approx(0.97)
    # ... so the next block is due one block period later, not at once (a burst of 97 blocks)
    assert p.wait_s(4 * BLOCK, now_s=1.0) == pytest.approx(BLOCK / FS)


def amplifier_with_watchdog(watchdog_s):
    emu = CurrentAmplifierEmulator(serial=False)
    wd = mb.REGISTERS["watchdog"]
    ctl = mb.REGISTERS["control"]
    for reg, raw in ((wd, wd.to_raw(watchdog_s)), (ctl, mb.CONTROL["ENABLE"])):
        reply = emu.handle_pdu(struct.pack(">BHH", 0x06, reg.address, raw))
        assert reply[0] == 0x06, reply
    return emu


def blocks(first, n):
    return [SampleBlock(first + k * BLOCK, FS, {"current_A": np.zeros(BLOCK)}) for k in range(n)]


def test_amplifier_watchdog_counts_samples_not_wall_time():
    emu = amplifier_with_watchdog(0.5)
    try:
        for b in blocks(0, 50):  # 0.5 s of samples since the last request (fed in a few ms)
            emu.on_block(b)
        assert emu.output_on and not emu.latched
        emu.handle_pdu(struct.pack(">BHH", 0x03, mb.REGISTERS["status"].address, 1))  # the host polls
        for b in blocks(50 * BLOCK, 50):
            emu.on_block(b)
        assert emu.output_on  # 0.5 s since that poll: not more
        emu.on_block(blocks(100 * BLOCK, 1)[0])  # 0.51 s without a request
        assert not emu.output_on and emu.latched == mb.FAULTS["WATCHDOG"]
    finally:
        emu.close()


def test_stream_faults_armed_at_a_sample_index_hit_exactly_those_frames():
    faults = Faults()
    emitter = FrameEmitter(2, 500, faults)
    faults.arm("drop_frames", 2, at_index=1500)
    faults.arm("corrupt_frames", 1, at_index=4000)
    faults.silence(5000, 1000)
    got = []
    for b in blocks(0, 7):
        for raw in emitter.emit(b.first_index, b.channels["current_A"][None, :]):
            try:
                got.append(decode_frame(raw).first_index)
            except FrameError:
                got.append("bad CRC")
    # 1500 and 2000 dropped, 4000 damaged, 5000-5999 silent
    assert got == [0, 500, 1000, 2500, 3000, 3500, "bad CRC", 4500, 6000, 6500]
    assert emitter.corrupted == 1
    assert emitter.dropped == 4 and faults.drop_frames == 0 and faults.corrupt_frames == 0
    assert not faults.is_silent(6000) and faults.is_silent(5999)


def test_a_rig_that_fails_trips_the_amplifier_and_says_why_without_stopping_the_clock(monkeypatch, caplog):
    """The rig refuses a block: the clock does not stop (which the drivers would report seconds
    later as a lost stream, with no cause); the amplifier latches INTERLOCK (its driver's next poll
    raises FaultLatched) and the rig's output goes off; the same samples come with no current, to
    every instrument; the cause (rig, sample, error) is logged once and kept in ``failure``."""
    import logging

    from hystbench.errors import SimulationError
    from hystbench.sim_backend.emulators.bench import EmulatedBench

    emu = EmulatedBench()
    try:
        emu.amplifier.enabled = True
        emu.rig.output_enabled = True
        emu.rig.set_excitation(320.0, 1.0, 0.0)
        real = emu.rig.actuator.step
        cause = "ecore_pm (rigs/ecore_pm.toml): the iron's field did not converge at 320 Hz"

        def refuse_with_current(t_s, current_a, dcurrent_dt):
            if np.any(current_a != 0.0):
                raise SimulationError(cause)
            return real(t_s, current_a, dcurrent_dt)

        monkeypatch.setattr(emu.rig.actuator, "step", refuse_with_current)
        first = emu.rig.next_index
        with caplog.at_level(logging.ERROR, logger="hystbench.emulators"):
            block = emu.tick()
        assert block.first_index == first and block.n == emu.block_samples  # no gap: the same samples
        assert np.max(np.abs(block.channels["current_A"])) < 0.01  # noise only (1 A-pp was asked)
        assert not emu.rig.output_enabled
        assert emu.amplifier.latched == mb.FAULTS["INTERLOCK"] and not emu.amplifier.output_on
        assert emu.amplifier._clock_end == block.end_index  # the instruments had the block
        assert emu.failure is not None and "ecore_pm" in emu.failure and cause in emu.failure
        assert f"sample {first}" in emu.failure
        said = [r.getMessage() for r in caplog.records if cause in r.getMessage()]
        assert len(said) == 1 and "INTERLOCK" in said[0]
        caplog.clear()
        assert emu.tick().first_index == block.end_index  # and on it goes, quietly
        assert not [r for r in caplog.records if r.levelno >= logging.ERROR]
    finally:
        emu.close()


def _bench_file(tmp_path, old: str, new: str):
    from pathlib import Path

    from hystbench.drivers.protocols.bench_config import load_bench_config

    text = (Path(__file__).parents[2] / "hystbench" / "config" / "bench.toml").read_text()
    assert old in text
    (tmp_path / "bench.toml").write_text(text.replace(old, new, 1))
    return load_bench_config(tmp_path / "bench.toml")


def test_a_can_interface_python_can_does_not_know_is_refused_naming_the_file_and_key(tmp_path):
    """``interface = "socketcann"`` was a CanInterfaceNotImplementedError traceback from record, emulate
    and the daemon (and, on a reload, ended the daemon); the emulators made before it are closed."""
    import threading

    from hystbench.errors import ConfigError
    from hystbench.sim_backend.emulators.bench import EmulatedBench

    before = {t.ident for t in threading.enumerate()}
    cfg = _bench_file(tmp_path, 'interface = "virtual"', 'interface = "socketcann"')
    with pytest.raises(ConfigError, match=r"bench\.toml: emulated flux_integrator: interface 'socketcann'.*"
                                          r"check \[flux_integrator\] interface and channel"):
        EmulatedBench(cfg)
    left = [t for t in threading.enumerate() if t.ident not in before and t.name.startswith("emu-")]
    for t in left:  # the servers' threads notice the closed sockets within their poll
        t.join(timeout=5.0)
    assert not [t.name for t in left if t.is_alive()]


def test_an_integrator_on_hardware_is_never_emulated_on_its_bus(tmp_path):
    """With ``backend = "hardware"`` the emulated bench joined the configured CAN bus as node 16, beside
    the real integrator: its emulator now stays on a private virtual channel."""
    from hystbench.sim_backend.emulators.bench import EmulatedBench

    cfg = _bench_file(tmp_path, '[flux_integrator]\nbackend = "sim"\ninterface = "virtual"    # python-can interface; '
                      '"socketcan" with channel = "can0" on hardware\nchannel = ""',
                      '[flux_integrator]\nbackend = "hardware"\ninterface = "socketcan"\nchannel = "can0"')
    emu = EmulatedBench(cfg)
    try:
        assert emu.integrator.addresses["can_interface"] == "virtual"
        assert emu.integrator.addresses["can_channel"].startswith("hystbench-emu-")
    finally:
        emu.close()


def test_the_drivers_say_which_can_interface_they_cannot_open():
    """On hardware the driver's own bus: an unknown interface is the bench file's error (it was called
    "unexpected answer to 'open'"), a device that is not there names the interface and channel."""
    from hystbench.drivers.base import Backoff
    from hystbench.drivers.flux_integrator import CanFluxIntegrator
    from hystbench.errors import ConfigError, ConnectionLost

    with pytest.raises(ConfigError, match=r"^flux_integrator: interface 'socketcann', channel 'x': python-can cannot"):
        CanFluxIntegrator(interface="socketcann", channel="x", node=16, backoff=Backoff(0.001, 2, 0.002, 1)).open()
    with pytest.raises(ConnectionLost, match=r"flux_integrator: CAN interface 'socketcan', channel 'nosuchcan0'"):
        CanFluxIntegrator(interface="socketcan", channel="nosuchcan0", node=16, backoff=Backoff(0.001, 2, 0.002, 1)).open()


@pytest.mark.parametrize("rig, missing", [("toroid", "no force channel"), ("voicecoil_ferrite", "no flux channel")])
def test_a_rig_the_emulated_bench_cannot_stream_is_refused_naming_the_key(tmp_path, rig, missing):
    """record and emulate with [sim] rig = "toroid" streamed no force, per-block errors for 20 s, then
    "sample stream lost"; only the daemon checked it.  Now the emulated bench itself refuses it."""
    from hystbench.errors import ConfigError
    from hystbench.sim_backend.emulators.bench import EmulatedBench

    cfg = _bench_file(tmp_path, 'rig = "ecore_pm"', f'rig = "{rig}"')
    with pytest.raises(ConfigError, match=rf"bench\.toml \[sim\] rig: '{rig}' has {missing}"):
        EmulatedBench(cfg)
