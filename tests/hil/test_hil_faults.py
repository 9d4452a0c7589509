"""Every injected fault and its documented reaction (docs/faults.md): exact gaps for stream damage,
reconnection with back-off, a clear error naming instrument and command, and the output off first.
No sample may be lost silently or invented: every delivered sample is checked against the rig.

Stream faults are placed at a sample index ahead of the emulator's clock, inside what the test then
acquires; waits are on the clock or on the event itself, never on wall time, so the outcome is the
same on an idle machine and on a busy one."""

import threading

import numpy as np
import pytest

from hystbench.blocks import BlockFlags
from hystbench.drivers.current_amplifier import ModbusError
from hystbench.drivers.protocols.modbus_map import REGISTERS as R
from hystbench.drivers.safety import SafetyLimitError
from hystbench.drivers.signal_generator import ScpiError
from hystbench.errors import ConnectionLost, InstrumentError, InstrumentTimeout, ProtocolError

from .conftest import HANG_S, acquire_through, expected_wire, skip_to, switched_on_at

pytestmark = pytest.mark.slow(20)  # ~20 s: handed to a worker before lighter files (tests/conftest.py)


def streams_flowing(hil):
    """The four streams open, each with frames received, and what the clock made before the output
    came on dropped (see ``skip_to``): what is acquired from now on was made with the output on."""
    streams = hil.bench.open_streams()
    hil.wait_for(lambda: all(s.stats.frames > 0 for s in streams.values()), "frames on every stream")
    skip_to(hil, switched_on_at(hil))
    return streams


def acquire_past(hil, faults, name):
    """Acquire until past the frames a fault armed on ``faults.name`` hit (it is consumed by then)."""
    hil.wait_for(lambda: not getattr(faults, name), f"the emulator applying {name}")
    return acquire_through(hil, hil.blocks_ahead(1))


def check_runs(hil, runs):
    """Samples are the rig's at their indices, and kept + missing = the whole span, exactly."""
    for r in runs:
        for name in r.channels:
            np.testing.assert_allclose(r.channels[name], expected_wire(hil, name, r.first_index, r.n),
                                       rtol=1e-12, atol=0, err_msg=f"{name} at {r.first_index}")
    span = runs[-1].end_index - runs[0].first_index
    assert sum(r.n for r in runs) + sum(r.gap_samples for r in runs[1:]) == span
    for a, b in zip(runs, runs[1:]):
        assert b.flags & BlockFlags.GAP and b.gap_samples == b.first_index - a.end_index > 0
    return sum(r.gap_samples for r in runs[1:])


def output_is_off(hil):
    return not hil.emu.rig.output_enabled and not (hil.emu.generator.state["output"] and hil.emu.amplifier.enabled)


# --- stream damage: exact gaps, no fault ------------------------------------------------------------
def test_crc_errors_on_the_serial_stream_give_an_exact_gap(hil):
    hil.bench.start_output()
    streams = streams_flowing(hil)
    faults = hil.emu.charge_amp.faults
    faults.arm("corrupt_frames", 3, at_index=hil.blocks_ahead(2))
    runs = acquire_past(hil, faults, "corrupt_frames")
    assert check_runs(hil, runs) == 3 * 500
    st = streams["charge_amplifier"].stats
    assert st.deframer.corrupt == 3 and st.frames_lost == 3 and st.gap_samples == 1500
    assert not hil.bench.faults


def test_dropped_can_fd_frames_give_an_exact_gap(hil):
    hil.bench.start_output()
    streams = streams_flowing(hil)
    faults = hil.emu.integrator.faults
    faults.arm("drop_frames", 7, at_index=hil.blocks_ahead(2))  # after the first acquired sample, always
    runs = acquire_past(hil, faults, "drop_frames")
    # a block's first frame on: 7 whole frames of 17 samples (a block holds hundreds of them)
    assert check_runs(hil, runs) == 7 * 17
    assert streams["flux_integrator"].stats.frames_lost == 7


def test_garbage_bytes_on_both_stream_kinds_lose_nothing(hil):
    hil.bench.start_output()
    streams = streams_flowing(hil)
    junk = bytes(range(1, 200))  # no 0x00 (COBS delimiter) and no frame magic
    at = hil.blocks_ahead(2)
    hil.emu.amplifier.faults.arm("stream_garbage", junk, at_index=at)  # TCP, length-prefixed
    hil.emu.charge_amp.faults.arm("stream_garbage", junk, at_index=at)  # serial, COBS
    acquire_past(hil, hil.emu.amplifier.faults, "stream_garbage")
    runs = acquire_past(hil, hil.emu.charge_amp.faults, "stream_garbage")
    assert check_runs(hil, runs) == 0 and len(runs) == 1
    amp, ca = streams["current_amplifier"].stats, streams["charge_amplifier"].stats
    assert amp.deframer.discarded_bytes == len(junk) and amp.deframer.resyncs == 1
    assert ca.deframer.corrupt == 1 and ca.gap_samples == 0


def test_stream_connection_lost_and_back_is_reconnected_with_an_exact_gap(hil_factory):
    hil = hil_factory(**{"bench.backoff.attempts": "1000"})  # however late the cable comes back
    hil.bench.start_output()
    streams = streams_flowing(hil)
    server = hil.emu.generator.stream.server
    server.pause()
    hil.wait_clock(hil.blocks_ahead(2))  # frames made while the cable is out are lost
    resumed_at = hil.emu.next_index
    server.resume()
    runs = acquire_through(hil, resumed_at + hil.emu.block_samples)
    gap = check_runs(hil, runs)
    assert gap > 0 and len(runs) == 2
    assert streams["signal_generator"].stats.reconnects >= 1
    assert not hil.bench.faults  # the control connection never went away


# --- instrument faults: output off first, a clear error, reconnection ----------------------------
def test_disconnect_switches_output_off_then_reconnects_with_backoff(hil):
    bench = hil.bench
    bench.start_output()
    assert hil.emu.rig.output_enabled
    hil.emu.generator.disconnect()
    hil.wait_for(lambda: bench.faults, "a bench fault")
    fault = bench.faults[0]
    assert fault.instrument == "signal_generator" and fault.output_off
    assert "connection lost" in fault.message
    assert not hil.emu.amplifier.enabled and not hil.emu.rig.output_enabled  # the amplifier cut the current
    with pytest.raises(InstrumentError, match="bench stopped: signal_generator"):
        bench.acquire(0.1)
    with pytest.raises(ConnectionLost, match="could not reconnect after 4 attempts"):
        bench.reconnect("signal_generator")  # cable still out: back-off runs out
    hil.emu.generator.reconnect()
    bench.reconnect("signal_generator")
    assert bench.generator.reconnects == 1 and hil.emu.generator.state["output"] is False
    bench.clear_faults()
    bench.start_output()
    skip_to(hil, switched_on_at(hil))
    runs = bench.acquire(0.1)
    check_runs(hil, runs)


def test_modbus_exception_response_is_a_clear_error_and_output_goes_off(hil):
    bench = hil.bench
    bench.start_output()
    bench.pause_heartbeat()  # the exception is for the next request, which must be ours
    hil.emu.amplifier.faults.modbus_exception, hil.emu.amplifier.faults.modbus_exception_count = 4, 1
    with pytest.raises(ModbusError, match=r"write gain \(register 5\) = 400 -> Modbus exception 4 "
                                          r"\(SERVER DEVICE FAILURE\)"):
        bench.configure("current_amplifier", gain_a_per_v=0.4)
    assert output_is_off(hil) and hil.emu.generator.state["output"] is False
    assert bench.faults[-1].instrument == "current_amplifier"


def test_repeated_modbus_exceptions_in_the_heartbeat_stop_the_bench(hil):
    hil.bench.start_output()
    hil.emu.amplifier.faults.modbus_exception, hil.emu.amplifier.faults.modbus_exception_count = 6, 3
    hil.wait_for(lambda: hil.bench.faults, "a bench fault")
    assert "SERVER DEVICE BUSY" in hil.bench.faults[0].message and hil.bench.faults[0].output_off
    assert not hil.emu.generator.state["output"]


def test_scpi_error_in_the_queue_names_the_command(hil):
    hil.bench.start_output()
    hil.emu.generator.push_error(-222)
    with pytest.raises(ScpiError, match=r"'FREQ 100' -> -222,\"Data out of range\""):
        hil.bench.configure("signal_generator", frequency_hz=100.0)
    assert output_is_off(hil)


def test_slow_and_missing_replies(hil_factory):
    hil = hil_factory(**{"charge_amplifier.timeout_s": "1.0", "current_amplifier.timeout_s": "0.2"})
    hil.bench.pause_heartbeat()  # every reply is to one of the queries below
    ca, faults = hil.bench.charge_amp, hil.emu.charge_amp.faults
    faults.reply_delay_s = 0.05  # slow but in time
    assert ca.query("scale_n_per_v") == 50.0
    faults.reply_delay_s = 0.0
    faults.hold_replies = release = threading.Event()  # too slow: held until the driver gave up
    sent = faults.replies_sent
    with pytest.raises(InstrumentTimeout, match=r"charge_amplifier: no answer to 'SC\?' within 1 s"):
        ca.query("scale_n_per_v")
    faults.hold_replies = None
    release.set()
    assert faults.wait_replies(sent + 1, HANG_S)  # the late reply is on the line now ...
    hil.wait_for(lambda: ca.link.waiting, "the late reply reaching the host")  # ... and at the host
    assert ca.query("time_constant") == "LONG"  # and was not taken for this one
    hil.emu.amplifier.faults.drop_replies = 1  # a missing Modbus reply
    amp = hil.bench.amplifier
    with pytest.raises(InstrumentTimeout, match=r"no answer to 'read 1 register\(s\) from 5 \(gain\)'"):
        amp.read("gain")
    assert amp.read("gain") == 0.5


def test_garbage_on_a_command_channel_is_a_protocol_error(hil):
    hil.bench.pause_heartbeat()  # the garbage goes before the next reply, which must be ours
    hil.emu.generator.faults.garbage = b"\x07\x13junk"
    with pytest.raises(ProtocolError, match=r"signal_generator: unexpected answer to 'OUTP\?'"):
        hil.bench.generator.query("output")
    assert hil.bench.generator.query("output") is False


def test_amplifier_fault_bits_stop_the_output(hil):
    hil.bench.start_output()
    hil.emu.amplifier.trip("OVERTEMP")
    hil.wait_for(lambda: hil.bench.faults, "a bench fault")
    assert "OVERTEMP" in hil.bench.faults[0].message
    assert output_is_off(hil) and not hil.emu.generator.state["output"]
    with pytest.raises(InstrumentError, match="OVERTEMP"):
        hil.bench.acquire(0.1)


def test_current_limit_trips_the_amplifier(hil):
    """The amplifier's own protection, the last one: its limit lowered at the amplifier itself (the
    front panel; the drivers refuse to, see the next test) below the sine's 0.7 A peak trips it."""
    amp = hil.emu.amplifier
    with amp._lock:
        amp.regs[R["current_limit"].address] = R["current_limit"].to_raw(0.5)
    hil.bench.start_output()
    hil.wait_for(lambda: hil.bench.faults, "a bench fault")
    assert "OVERCURRENT" in hil.bench.faults[0].message and output_is_off(hil)


def test_watchdog_disables_the_amplifier_when_the_host_falls_silent(hil):
    hil.bench.start_output()
    streams_flowing(hil)
    hil.bench.pause_heartbeat()
    hil.wait_for(lambda: hil.emu.amplifier.latched, "the watchdog tripping")
    assert not hil.emu.amplifier.output_on  # the amplifier's own output goes off as it latches
    # the rig follows in the same call, just after the latch (a loaded run once looked in between)
    hil.wait_for(lambda: not hil.emu.rig.output_enabled, "the rig following the amplifier")
    t_trip, settings = hil.emu.changes[-1]  # the first sample with the output off
    assert settings["output"] is False
    stream = hil.bench.streams["current_amplifier"]
    tail = []
    while not tail or tail[-1].end_index < t_trip + 5000:
        b = stream.read(HANG_S)
        assert b is not None, "the current stream stopped"
        tail.append(b)
    after = np.concatenate([b.channels["current_A"][max(0, t_trip - b.first_index):] for b in tail
                            if b.end_index > t_trip])
    assert after.size and np.max(np.abs(after)) < 5e-3  # sensor noise only (the sine peaked at 0.7 A)
    st = hil.bench.amplifier.read_status()
    assert st.faults == ("WATCHDOG",) and not st.values["enabled"]


def test_charge_amplifier_overload_flags_clip_but_keeps_running(hil):
    hil.bench.configure("charge_amplifier", scale_n_per_v=10.0)  # 220 N -> 22 V: beyond +-10 V
    hil.bench.start_output()
    runs = hil.bench.acquire(0.05)
    assert runs[0].flags & BlockFlags.CLIP
    assert np.max(runs[0].channels["force_N"]) == pytest.approx(100.0)  # 10 V x 10 N/V
    assert "OVERLOAD" in hil.bench.charge_amp.status().faults and not hil.bench.faults


def test_integrator_bus_off_raises_with_the_output_already_off(hil_factory):
    hil = hil_factory(**{"flux_integrator.timeout_s": "0.2", "bench.stall_timeout_s": "0.5"})  # a silent bus: a stall
    hil.bench.start_output()
    streams_flowing(hil)
    hil.emu.integrator.disconnect()
    with pytest.raises(InstrumentError) as info:
        hil.bench.acquire(5.0, timeout_s=HANG_S)
    assert "flux_integrator" in str(info.value)
    assert output_is_off(hil) and hil.bench.faults[0].output_off


def test_safety_limits_are_refused_before_anything_is_sent(hil):
    bench, emu = hil.bench, hil.emu
    sent = len(emu.generator.commands_seen)
    with pytest.raises(SafetyLimitError, match=r"exceeds the command limit 1.71 A \(max_current_a 2 A, amplifier trip 1.8 A"):
        bench.configure("signal_generator", amplitude_vpp=7.2)  # 3.6 V x 0.5 A/V = 1.8 A: the trip level itself
    with pytest.raises(SafetyLimitError):
        bench.configure("current_amplifier", gain_a_per_v=1.5)  # 1.4 V x 1.5 A/V = 2.1 A
    with pytest.raises(SafetyLimitError):
        bench.configure("current_amplifier", current_limit_a=2.5)
    with pytest.raises(SafetyLimitError, match="lower the excitation first"):
        bench.configure("current_amplifier", current_limit_a=0.5)  # below the sine's 0.7 A peak: it would trip
    with pytest.raises(SafetyLimitError):
        bench.generator.upload_waveform(np.linspace(-1.0, 4.5, 256), 320.0)
    assert len(emu.generator.commands_seen) == sent
    assert emu.generator.state["amplitude_vpp"] == 2.8 and emu.amplifier.gain_a_per_v == 0.5
    assert not bench.faults  # a refusal changes nothing, so it is not a fault


def test_serial_instrument_silent_for_a_moment_gives_an_exact_gap_and_no_stop(hil_factory):
    hil = hil_factory(**{"sim.block_samples": "1000"})  # 10 ms ticks: the silence is 10 of them, shorter
    hil.bench.start_output()  # than two of the heartbeat's 1 s reply deadlines (then it is a fault)
    streams = streams_flowing(hil)
    span = 10 * hil.emu.block_samples  # serial cable out for 0.1 s: no replies, no frames (all of
    # it: set before the clock can reach its start, however busy the machine)
    at = hil.arm_ahead(2, lambda at: hil.emu.charge_amp.faults.silence(at, span))
    runs = acquire_through(hil, at + span + hil.emu.block_samples)
    gap = check_runs(hil, runs)
    assert gap == span and streams["charge_amplifier"].stats.gap_samples == gap
    assert not hil.bench.faults and hil.emu.rig.output_enabled  # the other heartbeats kept the watchdog fed
