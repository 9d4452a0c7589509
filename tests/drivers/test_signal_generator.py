"""Signal generator driver: byte-exact SCPI transcripts, error-queue handling and the current budget."""

import numpy as np
import pytest

from hystbench.drivers.protocols import scpi
from hystbench.drivers.safety import CurrentBudget, SafetyLimitError
from hystbench.drivers.signal_generator import ScpiError, ScpiSignalGenerator
from hystbench.errors import ConfigError, InstrumentTimeout, ProtocolError

OK = b'0,"No error"\n'
OPEN = [
    (b"*IDN?\n", b"ACME,GEN-7,1234,2.1\n"),
    (b"*RST\n", None),
    (b"*CLS\n", None),
    (b"SYST:ERR?\n", OK),
    (b"FUNC?\n", b"SIN\n"),
    (b"FREQ?\n", b"1000\n"),
    (b"VOLT?\n", b"0.1\n"),
    (b"VOLT:OFFS?\n", b"0\n"),
    (b"OUTP?\n", b"0\n"),
]
CLOSE = [(b"OUTP OFF\n", None), (b"OUTP?\n", b"0\n")]


def gen(peer, max_a=2.0, gain=0.5, timeout_s=10.0):
    """The driver on the scripted peer; the timeout is generous unless a test waits for it to pass
    (then no reply is scripted: it passes however busy the machine is)."""
    return ScpiSignalGenerator(peer.url, budget=CurrentBudget(max_a, gain), timeout_s=timeout_s)


def test_open_sine_output_close_byte_exact(scripted_peer):
    peer = scripted_peer(OPEN + [
        (b"FREQ 320\n", None), (b"SYST:ERR?\n", OK),
        (b"VOLT 2.8\n", None), (b"SYST:ERR?\n", OK),
        (b"VOLT:OFFS 0.5\n", None), (b"SYST:ERR?\n", OK),
        (b"OUTP ON\n", None), (b"SYST:ERR?\n", OK),
    ] + CLOSE)
    with gen(peer) as g:
        assert g.identity == {"manufacturer": "ACME", "model": "GEN-7", "serial": "1234", "firmware": "2.1"}
        g.set_sine(320.0, 2.8, 0.5)
        g.set_output(True)
        assert g.budget.command_peak_v == pytest.approx(1.9)
    peer.check()


def test_error_queue_entry_names_the_command_and_is_drained(scripted_peer):
    peer = scripted_peer(OPEN + [
        (b"FREQ 320\n", None),
        (b"SYST:ERR?\n", b'-222,"Data out of range"\n'),
        (b"SYST:ERR?\n", b'-350,"Queue overflow"\n'),
        (b"SYST:ERR?\n", OK),
    ] + CLOSE)
    with gen(peer) as g:
        with pytest.raises(ScpiError, match=r"'FREQ 320' -> -222,\"Data out of range\"; -350") as info:
            g.set("frequency_hz", 320.0)
        assert info.value.errors == [(-222, "Data out of range"), (-350, "Queue overflow")]
    peer.check()


def test_amplitude_order_keeps_every_intermediate_state_in_budget(scripted_peer):
    # from 0.1 Vpp / +3 V offset to 7 Vpp / 0 V: the offset must go down first (budget 4 V peak)
    peer = scripted_peer(OPEN[:-2] + [(b"VOLT:OFFS?\n", b"3\n"), (b"OUTP?\n", b"0\n"),
                                      (b"FREQ 100\n", None), (b"SYST:ERR?\n", OK),
                                      (b"VOLT:OFFS 0\n", None), (b"SYST:ERR?\n", OK),
                                      (b"VOLT 7\n", None), (b"SYST:ERR?\n", OK)] + CLOSE)
    with gen(peer) as g:
        g.set_sine(100.0, 7.0, 0.0)
    peer.check()


def test_budget_refusal_sends_nothing(scripted_peer):
    peer = scripted_peer(OPEN + CLOSE)
    with gen(peer, max_a=1.0, gain=0.5) as g:  # 1 A / 0.5 A/V = 2 V peak
        with pytest.raises(SafetyLimitError, match=r"1.05 A exceeds the command limit 0.95 A \(max_current_a 1 A, less 5 %"):
            g.set_sine(320.0, 4.2, 0.0)
        with pytest.raises(SafetyLimitError):
            g.set("offset_v", 2.5)
        with pytest.raises(SafetyLimitError, match="DATA:ARB:DAC"):
            g.upload_waveform(np.linspace(-2.5, 1.0, 64), 100.0)
        with pytest.raises(ConfigError, match="FREQ"):
            g.set("frequency_hz", -5.0)
    peer.check()


def test_waveform_upload_is_a_definite_length_block(scripted_peer):
    table = np.array([0.0, 1.0, 0.0, -1.0] * 2)  # 8 points, +-1 V
    block = scpi.encode_block(np.array([0, 32767, 0, -32767] * 2, dtype="<i2").tobytes())
    peer = scripted_peer(OPEN + [
        (b"DATA:ARB:DAC " + block + b"\n", None), (b"SYST:ERR?\n", OK),
        (b"FREQ 50\n", None), (b"SYST:ERR?\n", OK),
        (b"VOLT 2\n", None), (b"SYST:ERR?\n", OK),
        (b"VOLT:OFFS 0\n", None), (b"SYST:ERR?\n", OK),
        (b"FUNC ARB\n", None), (b"SYST:ERR?\n", OK),
    ] + CLOSE)
    with gen(peer) as g:
        g.upload_waveform(table, 50.0)
        assert g.state["function"] == "ARB"
    peer.check()


def test_missing_reply_is_a_timeout_naming_the_command(scripted_peer):
    peer = scripted_peer(OPEN + [(b"FREQ?\n", None)] + CLOSE)
    with gen(peer, timeout_s=0.5) as g:
        with pytest.raises(InstrumentTimeout, match=r"signal_generator: no answer to 'FREQ\?' within 0.5 s"):
            g.query("frequency_hz")
    peer.check()


def test_garbled_identity_is_a_protocol_error(scripted_peer):
    peer = scripted_peer([(b"*IDN?\n", b"\x13\x07garbage\n")])
    with pytest.raises(ProtocolError, match=r"\*IDN\? answer"):
        gen(peer).open()
    peer.check()


def test_scpi_headers_match_short_and_long_forms():
    assert scpi.header_matches("VOLTage:OFFSet", "volt:offset")
    assert scpi.header_matches("VOLTage:OFFSet", "VOLT:OFFS")
    assert not scpi.header_matches("VOLTage:OFFSet", "VOLT")
    assert {c.short for c in scpi.GENERATOR.values()} >= {"FREQ", "VOLT", "VOLT:OFFS", "OUTP", "SYST:ERR"}
