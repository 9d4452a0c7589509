"""The SCPI digitiser through real pyvisa-py on 127.0.0.1: byte-exact transcripts of what goes on
the wire (arm, trigger, preamble, waveform queries) per dialect, the IEEE 488.2 block's failures
(each a clear error naming instrument and command, nothing invented), and the joining of
per-channel segments with exact gaps."""

from __future__ import annotations

import numpy as np
import pytest

from hystbench.blocks import BlockFlags
from hystbench.drivers.digitiser import DigitiserFrameSource, ScpiDigitiser, SegmentJoiner, VisaLink
from hystbench.drivers.protocols import scpi_digitiser as sd
from hystbench.errors import InstrumentTimeout, ProtocolError

OK = b'0,"No error"\n'
IDN = b"ACME,DIG-4,123,1.0\n"

GENERIC_OPEN = [
    (b"*IDN?\n", IDN), (b"*CLS\n", None),
    (b"ROSC:SOUR EXT\n", None), (b"SYST:ERR?\n", OK),
    (b"TRIG:SOUR EXT\n", None), (b"SYST:ERR?\n", OK),
    (b"WAV:FORM WORD\n", None), (b"SYST:ERR?\n", OK),
    (b"WAV:UNS OFF\n", None), (b"SYST:ERR?\n", OK),
    (b"WAV:BYT LSBF\n", None), (b"SYST:ERR?\n", OK),
    (b"WAV:POIN:MODE RAW\n", None), (b"SYST:ERR?\n", OK),
    (b"WAV:POIN 1000\n", None), (b"SYST:ERR?\n", OK),
    (b"ACQ:SRAT?\n", b"100000\n"),
    (b"RUN\n", None), (b"SYST:ERR?\n", OK),
]
ESR0 = b"0\n"  # Tektronix: *ESR? with no error bit: the event queue is not read
TEK_OPEN = [
    (b"*IDN?\n", b"TEKTRONIX,MSO44,C0001,CF:91.1CT FV:1.0\n"), (b"*CLS\n", None),
    (b"HEADer OFF\n", None), (b"*ESR?\n", ESR0),
    (b"ROSC:SOUR EXT\n", None), (b"*ESR?\n", ESR0),
    (b"TRIG:A:EDGE:SOU AUX\n", None), (b"*ESR?\n", ESR0),
    (b"DAT:ENC SRI\n", None), (b"*ESR?\n", ESR0),
    (b"WFMO:BYT_N 2\n", None), (b"*ESR?\n", ESR0),
    (b"HOR:MODE:SAMPLER?\n", b"1.0E+5\n"),
    (b"ACQ:STATE RUN\n", None), (b"*ESR?\n", ESR0),
]
# a peer left with bytes the driver never read sees its close as a reset: not the driver's business
pytestmark = pytest.mark.filterwarnings("ignore::pytest.PytestUnhandledThreadExceptionWarning")


def digitiser(peer, dialect="generic", timeout_s=2.0) -> ScpiDigitiser:
    link = VisaLink(f"TCPIP::127.0.0.1::{peer.port}::SOCKET", timeout_s)
    return ScpiDigitiser(link, sd.dialect(dialect), 100_000.0, max_points=1000)


@pytest.mark.parametrize("dialect, opening, fetch", [
    ("generic", GENERIC_OPEN, [
        (b"WAV:SOUR CHAN2;:WAV:PRE?\n", b"1,0,3,1,1e-05,0.0125,0,0.5,1.0,0\n"),
        (b"WAV:DATA?\n", b"#16\xfe\xff\x00\x00\x03\x00\n")]),
    ("tektronix", TEK_OPEN, [
        (b"DAT:SOU CH2;:WFMO?\n", b'2;16;BIN;RI;LSB;"Ch2, DC coupling, 1 V/div";3;Y;"s";1.0E-5;1.25E-2;0;"V";5.0E-1;0.0E+0;1.0E+0\n'),
        (b"CURV?\n", b"#16\xfe\xff\x00\x00\x03\x00\n")]),
])
def test_transcript_open_arm_and_one_waveform_read(scripted_peer, dialect, opening, fetch):
    ch = "CHAN2" if dialect == "generic" else "CH2"
    select = [(b"WAV:SOUR CHAN2\n", None), (b"SYST:ERR?\n", OK)] if dialect == "generic" else \
        [(b"DAT:SOU CH2\n", None), (b"*ESR?\n", ESR0)]
    opening = opening[:-3] + select + opening[-3:]  # each channel selected once at open, with its check
    peer = scripted_peer(opening + fetch + [(b"STOP\n" if dialect == "generic" else b"ACQ:STATE STOP\n", None)])
    dig = digitiser(peer, dialect)
    dig.open((ch,))
    first, volts, clipped = dig.fetch(ch)
    dig.close()
    peer.check()
    # x_origin 12.5 ms at 100 kS/s is sample 1250; (code - 0) * 0.5 V + 1 V
    assert first == 1250 and not clipped
    np.testing.assert_array_equal(volts, [0.0, 1.0, 2.5])


def test_an_error_in_the_queue_after_a_setting_names_the_command_and_every_error(scripted_peer):
    peer = scripted_peer(GENERIC_OPEN[:6] + [
        (b"WAV:FORM WORD\n", None), (b"SYST:ERR?\n", b'-224,"Illegal parameter value"\n'),
        (b"SYST:ERR?\n", b'-113,"Undefined header"\n'), (b"SYST:ERR?\n", OK)])
    dig = digitiser(peer)
    with pytest.raises(ProtocolError, match=r"digitiser \(TCPIP::127.0.0.1::\d+::SOCKET\): 'WAV:FORM WORD': the "
                                            r'digitiser reports -224,"Illegal parameter value"; -113,"Undefined header"'):
        dig.open()
    dig.link.close()
    peer.check()


def test_a_sample_rate_other_than_the_bench_clock_is_refused(scripted_peer):
    from hystbench.errors import ConfigError

    peer = scripted_peer(GENERIC_OPEN[:16] + [(b"ACQ:SRAT?\n", b"250000\n")])
    with pytest.raises(ConfigError, match="samples at 250000 Hz but \\[bench\\] fs_hz = 100000"):
        digitiser(peer).open()
    peer.check()


def _fetch_with(scripted_peer, pre: bytes, data_reply: bytes, timeout_s: float = 2.0):
    peer = scripted_peer(GENERIC_OPEN + [(b"WAV:SOUR CHAN1;:WAV:PRE?\n", pre), (b"WAV:DATA?\n", data_reply)],
                         timeout_s=30.0)
    dig = digitiser(peer, timeout_s=timeout_s)
    dig.open()
    return peer, dig


PRE5 = b"1,0,5,1,1e-05,0,0,1,0,0\n"


@pytest.mark.parametrize("reply, error, message", [
    # a wrong length digit: '#1' announces one length digit where there are two: the data is off by one
    (b"#110\x01\x00\x02\x00\x03\x00\x04\x00\x05\x00\n", ProtocolError,
     r"no terminator after the 1 bytes the block announced .*the length does not match the data"),
    # a length digit that is no digit
    (b"#A10\x01\x00\x02\x00\x03\x00\x04\x00\x05\x00\n", ProtocolError, r"bad block header b'#A': length digit b'A'"),
    # an indefinite-length block
    (b"#0\x01\x00\x02\x00\n", ProtocolError, r"indefinite-length block \('#0'\) is not accepted"),
    # an error text where the block should be
    (b'-222,"Data out of range"\n', ProtocolError, r"expected a definite-length block"),
    # truncated: a complete block with fewer points than the preamble announced
    (b"#18\x01\x00\x02\x00\x03\x00\x04\x00\n", ProtocolError,
     r"the block holds 8 bytes, the preamble announced 5 points of 2 bytes"),
])
def test_a_malformed_block_is_a_protocol_error_naming_instrument_and_command(scripted_peer, reply, error, message):
    peer, dig = _fetch_with(scripted_peer, PRE5, reply)
    with pytest.raises(error, match=message) as info:
        dig.fetch("CHAN1")
    assert "digitiser (TCPIP::127.0.0.1::" in str(info.value) and "'WAV:DATA?'" in str(info.value)
    assert "(CHAN1)" in str(info.value)
    dig.link.close()


def test_a_timeout_mid_block_says_how_far_the_block_came(scripted_peer):
    # 10 bytes announced, 6 sent, then nothing: the read times out inside the data
    peer, dig = _fetch_with(scripted_peer, PRE5, b"#210\x01\x00\x02\x00\x03\x00", timeout_s=0.3)
    with pytest.raises(InstrumentTimeout, match=r"'WAV:DATA\?' \(CHAN1\): timed out in the binary block after 4 "
                                                r"bytes, waiting for 10 data bytes"):
        dig.fetch("CHAN1")
    dig.link.close()


def test_a_bad_block_under_the_frame_source_yields_no_frame_and_drops_the_session(scripted_peer):
    """The stream's reader reopens on ConnectionError: the lost segment becomes a gap there."""
    select = [(b"WAV:SOUR CHAN1\n", None), (b"SYST:ERR?\n", OK), (b"WAV:SOUR CHAN2\n", None), (b"SYST:ERR?\n", OK)]
    peer = scripted_peer(GENERIC_OPEN[:-3] + select + GENERIC_OPEN[-3:] + [
        (b"WAV:SOUR CHAN1;:WAV:PRE?\n", b"1,0,2,1,1e-05,0,0,1,0,0\n"),
        (b"WAV:DATA?\n", b"#14\x01\x00\x02\x00\n"),
        (b"WAV:SOUR CHAN2;:WAV:PRE?\n", b"1,0,2,1,1e-05,0,0,1,0,0\n"),
        (b"WAV:DATA?\n", b"#13\x01\x00\x02\x00\n")], timeout_s=30.0)
    link = VisaLink(f"TCPIP::127.0.0.1::{peer.port}::SOCKET", 2.0)
    src = DigitiserFrameSource(ScpiDigitiser(link, sd.dialect("generic"), 100_000.0, max_points=1000),
                               ["CHAN1", "CHAN2"])
    src.open()
    with pytest.raises(ConnectionError, match=r"'WAV:DATA\?' \(CHAN2\): no terminator"):
        src.read_frames(1.0)
    assert src.deframer_stats.frames == 0 and src.deframer_stats.corrupt == 1
    link.close()


# --- the block codec and the preamble, no transport -------------------------------------------------

def test_compound_messages_split_into_units_from_the_root_or_the_last_path():
    assert sd.compound("WAV:SOUR CHAN1", "WAV:PRE?") == "WAV:SOUR CHAN1;:WAV:PRE?"
    assert sd.split_units(b"WAV:SOUR CHAN1;:WAV:PRE?") == [b"WAV:SOUR CHAN1", b"WAV:PRE?"]
    assert sd.split_units(b":WAV:SOUR CHAN1;PRE?;*OPC?;DATA?") == [b"WAV:SOUR CHAN1", b"WAV:PRE?", b"*OPC?",
                                                                    b"WAV:DATA?"]


def test_encoded_blocks_read_back_and_the_preamble_round_trips_in_every_dialect():
    data = bytes(range(256)) * 5
    wire = sd.encode_block(data) + b"\n"
    assert wire[:6] == b"#41280"
    pos = 0

    def read(n):
        nonlocal pos
        out, pos = wire[pos:pos + n], pos + n
        return out

    assert sd.read_block(read, "x") == data
    pre = sd.Preamble(7, 1e-5, 123456 / 1e5, 0.0, 10 / 32768, 0.0, 0.0)
    for d in sd.DIALECTS.values():
        back = sd.Preamble.parse(pre.format(d), d)
        assert back == pre and back.first_index(1e5) == 123456


def test_a_segment_between_two_samples_of_the_clock_is_refused():
    with pytest.raises(ValueError, match="between two samples"):
        sd.Preamble(1, 1e-5, 0.5e-5, 0, 1, 0, 0).first_index(1e5)


def test_the_joiner_keeps_channels_aligned_and_a_jump_is_a_gap_never_filled():
    j = SegmentJoiner(2)
    j.push(0, 100, np.arange(100, 110, dtype=float), False)
    assert j.pop() is None  # channel 1 has nothing yet
    j.push(1, 100, -np.arange(100, 106, dtype=float), False)
    f = j.pop()
    assert f.first_index == 100 and f.n == 6
    np.testing.assert_array_equal(f.samples[0], np.arange(100, 106))
    np.testing.assert_array_equal(f.samples[1], -np.arange(100, 106))
    # channel 1 lost [106, 115): channel 0's samples there are dropped, the next frame starts at 115
    j.push(0, 110, np.arange(110, 120, dtype=float), True)
    j.push(1, 115, -np.arange(115, 118, dtype=float), False)
    f = j.pop()
    assert f.first_index == 115 and f.n == 3 and f.flags == 4  # CLIP from channel 0's segment
    np.testing.assert_array_equal(f.samples[0], np.arange(115, 118))
    np.testing.assert_array_equal(f.samples[1], -np.arange(115, 118))
    # an overlap (a segment read twice) adds only what is new
    j.push(1, 116, -np.arange(116, 120, dtype=float), False)
    f = j.pop()
    assert f.first_index == 118 and f.n == 2
    np.testing.assert_array_equal(f.samples[1], [-118, -119])


def test_docs_protocols_lists_every_command_of_every_dialect():
    """docs/protocols.md's digitiser table is written from the tables: each message is in it."""
    from pathlib import Path

    text = (Path(__file__).resolve().parents[2] / "docs" / "protocols.md").read_text()
    section = text.split("## Digitiser — SCPI over VISA", 1)[1].split("## Digitiser — NI-DAQmx", 1)[0]
    for d in sd.DIALECTS.values():
        for op, cmd in d.commands.items():
            msg = cmd.message(d.channel_names[0])[:-1] + "<n>" if op == "source" else cmd.message()
            assert f"`{msg}`" in section, (d.name, op, msg)
        for msg in d.on_open:
            assert f"`{msg}`" in section, (d.name, msg)


# --- review R1: what the preamble says must be what the driver assumes ---------------------------------
def test_points_further_apart_than_the_bench_clock_are_refused_not_read_as_consecutive_samples(scripted_peer):
    """A digitiser that decimates (e.g. a scope's screen-resolution read: x_increment = 2/fs) sends
    half the samples: read as consecutive samples of the clock they would be placed at the wrong
    indices.  The preamble's x_increment must be one period of [bench] fs_hz."""
    decimated = b"1,0,5,1,2e-05,0,0,1,0,0\n"
    peer, dig = _fetch_with(scripted_peer, decimated, b"#210\x01\x00\x02\x00\x03\x00\x04\x00\x05\x00\n")
    with pytest.raises(ProtocolError, match=r"'WAV:SOUR CHAN1;:WAV:PRE\?' \(CHAN1\): the points are 2e-05 s apart, "
                                            r"not one period of the 100000 Hz clock"):
        dig.fetch("CHAN1")
    dig.link.close()


@pytest.mark.parametrize("fields, wrong", [
    (b"2;16;BIN;RI;MSB", "byt_or"),   # most significant byte first: every code byte-swapped
    (b"2;16;BIN;RP;LSB", "bn_fmt"),   # unsigned codes: read as signed they wrap at half scale
    (b"1;8;BIN;RI;LSB", "byt_nr"),    # one byte a point
])
def test_a_tektronix_preamble_whose_encoding_is_not_the_one_read_is_refused(fields, wrong):
    d = sd.dialect("tektronix")
    text = fields.decode() + ';"Ch1, DC coupling";3;Y;"s";1.0E-5;0;0;"V";5.0E-1;0.0E+0;0.0E+0'
    with pytest.raises(ValueError, match=rf"preamble says {wrong} = "):
        sd.Preamble.parse(text, d)
    good = '2;16;BIN;RI;LSB;"Ch1, DC coupling";3;Y;"s";1.0E-5;0;0;"V";5.0E-1;0.0E+0;0.0E+0'
    assert sd.Preamble.parse(good, d).points == 3


def test_clip_goes_with_the_samples_of_the_clipped_segment_not_with_whichever_frame_is_next():
    """Review R1: a channel read later in a round holds more samples than the first; the part of its
    clipped segment past what every channel has goes out in the next frame, which must be flagged
    CLIP too (the flag was spent on the earlier frame).  A frame outside every clipped segment is not."""
    j = SegmentJoiner(2)
    j.push(0, 0, np.zeros(100), False)
    j.push(1, 0, np.zeros(150), True)  # clipped somewhere in 0..149
    assert j.pop().flags == int(BlockFlags.CLIP)
    j.push(0, 100, np.zeros(100), False)
    j.push(1, 150, np.zeros(50), False)
    f = j.pop()
    assert (f.first_index, f.n) == (100, 100) and f.flags == int(BlockFlags.CLIP)  # 100..149 from the clipped read
    j.push(0, 200, np.zeros(50), False)
    j.push(1, 200, np.zeros(50), False)
    assert j.pop().flags == 0


# --- review R1 / H8: what the instrument sends after *RST is not what the driver reads -----------------
def test_the_generic_open_asks_for_signed_codes_and_the_raw_memory_and_the_emulator_understands_both():
    """InfiniiVision sends unsigned WORD codes after *RST (read as int16: off by half scale, silently)
    and the decimated screen record unless :WAV:POIN:MODE RAW: the generic table must send both."""
    from hystbench.sim_backend.emulators.digitiser import DigitiserEmulator

    msgs = [c.message() for c in sd.dialect("generic").commands.values()]
    assert "WAV:UNS OFF" in msgs and "WAV:POIN:MODE RAW" in msgs
    emu = DigitiserEmulator(1e5, {"current_A": (1, 1.0)})
    try:
        for good in (b"WAV:UNS OFF", b"WAVeform:UNSigned off", b"WAV:POIN:MODE RAW"):
            emu.handle(good)
            assert not emu.errors, good
        emu.handle(b"WAV:UNS ON")  # the emulator sends signed codes only: it refuses what it cannot do
        assert [c for c, _ in emu.errors] == [-224]
    finally:
        emu.close()


# --- review R1 / H8: a Tektronix scope reads its errors as events, not from SYST:ERR? -----------------
def test_tektronix_errors_are_read_with_esr_then_allev_and_each_error_event_is_named(scripted_peer):
    """*ESR? with CME and EXE set (32 + 16): ALLEv? then gives every event at once; the status
    event 402 (operation complete) is no error and is not reported."""
    peer = scripted_peer(TEK_OPEN[:4] + [
        (b"ROSC:SOUR EXT\n", None), (b"*ESR?\n", b"49\n"),
        (b"ALLE?\n", b'113,"Undefined header; Command not found - ROSC:SOUR",402,"Operation complete",'
                     b'224,"Illegal parameter value"\n')])
    dig = digitiser(peer, "tektronix")
    with pytest.raises(ProtocolError, match=r"'ROSC:SOUR EXT': the digitiser reports 113,\"Undefined header; Command "
                                            r'not found - ROSC:SOUR\"; 224,"Illegal parameter value"$'):
        dig.open()
    dig.link.close()
    peer.check()


def test_allev_replies_parse_with_or_without_header_and_refuse_anything_else():
    assert sd.parse_event_reply('0,"No events to report - queue empty"') == []
    assert sd.parse_event_reply(':ALLEV 113,"Undefined header; unrecognized command"') == \
        [(113, "Undefined header; unrecognized command")]
    assert sd.parse_event_reply('ALLEV 113,"a ""quoted"" word",224,"b"') == [(113, 'a "quoted" word'), (224, "b")]
    for bad in ("", '0,"No error" junk', "32", '113,"unterminated'):
        with pytest.raises(ValueError, match="not an event-queue reply"):
            sd.parse_event_reply(bad)


@pytest.mark.parametrize("dialect, asks, answers", [
    ("generic", [b"SYST:ERR?", b"SYST:ERR?"], [b'-113,"Undefined header"', b'0,"No error"']),
    ("tektronix", [b"*ESR?", b"ALLE?", b"*ESR?", b"ALLE?"],
     [b"32", b'113,"Undefined header"', b"0", b'0,"No events to report - queue empty"']),
])
def test_the_emulator_reports_an_undefined_header_in_each_dialects_error_query(dialect, asks, answers):
    from hystbench.sim_backend.emulators.digitiser import DigitiserEmulator

    emu = DigitiserEmulator(1e5, {"current_A": (1, 1.0)}, dialect=dialect)
    try:
        emu.handle(b"NO:SUCH:HEADer 1")
        assert [emu.handle(a)[:-1] for a in asks] == answers
    finally:
        emu.close()


def test_clip_is_either_end_of_the_int16_code_range_not_a_symmetric_32767():
    """int16 codes run from -32768 to 32767: -32767 is an ordinary code one step inside full scale,
    -32768 the negative end (it was read as clipped at +-32767, the emulator's old full scale)."""
    assert not sd.clipped(np.array([-32767, 0, 32766], dtype="<i2"))
    assert sd.clipped(np.array([0, -32768], dtype="<i2")) and sd.clipped(np.array([32767], dtype="<i2"))
    assert not sd.clipped(np.array([], dtype="<i2"))
    codes, over = sd.volts_to_codes(np.array([-10.0, 10.0 - 10 / 32768]), 10 / 32768)  # both ends, not beyond
    assert codes.tolist() == [-32768, 32767] and not over
    assert sd.volts_to_codes(np.array([-10.001]), 10 / 32768)[1]


# --- review R1 / H8: segmented (triggered) acquisition of an oscilloscope --------------------------------
SEG_OPEN = GENERIC_OPEN[:-3] + [(b"WAV:SOUR CHAN1\n", None), (b"SYST:ERR?\n", OK), (b"ACQ:SRAT?\n", b"100000\n"),
                                (b"ACQ:MODE SEGM\n", None), (b"SYST:ERR?\n", OK),
                                (b"ACQ:SEGM:COUN 2\n", None), (b"SYST:ERR?\n", OK)]
# 3 points 10 us apart from 20 us before the trigger; codes 1, 2, 3 of 0.5 V
SEG_PRE = b"1,0,3,1,1e-05,-2e-05,0,0.5,0,0\n"
SEG_DATA = b"#16\x01\x00\x02\x00\x03\x00\n"


def _batch(tag2: bytes) -> list:
    return [(b"DIG\n", None), (b"*OPC?\n", b"1\n"), (b"SYST:ERR?\n", OK),
            (b"ACQ:SEGM:IND 1;:WAV:SEGM:TTAG?\n", b"+0.000000000E+00\n"),
            (b"WAV:SOUR CHAN1;:WAV:PRE?\n", SEG_PRE), (b"WAV:DATA?\n", SEG_DATA),
            (b"ACQ:SEGM:IND 2;:WAV:SEGM:TTAG?\n", tag2),
            (b"WAV:SOUR CHAN1;:WAV:PRE?\n", SEG_PRE), (b"WAV:DATA?\n", SEG_DATA)]


def _segmented_source(peer, clock=None) -> DigitiserFrameSource:
    link = VisaLink(f"TCPIP::127.0.0.1::{peer.port}::SOCKET", 2.0)
    return DigitiserFrameSource(ScpiDigitiser(link, sd.dialect("generic"), 100_000.0, max_points=1000), ["CHAN1"],
                                segments=2, **({"clock": clock} if clock else {}))


def test_segmented_transcript_one_batch_placed_exactly_by_the_time_tags(scripted_peer):
    """Armed once (DIGitize), waited for (*OPC?), then per segment its index, time tag, preamble and
    data.  Segment 2's trigger came 3.12 ms = 312 samples after segment 1's: it starts at index 312."""
    peer = scripted_peer(SEG_OPEN + _batch(b"+3.120000000E-03\n"), timeout_s=30.0)
    src = _segmented_source(peer)
    src.open()
    frames = src.read_frames(1.0)
    src.digitiser.link.close()
    peer.check()
    assert [(f.first_index, f.n) for f in frames] == [(0, 3), (312, 3)]
    assert all(f.flags == 0 for f in frames)  # the first batch: no gap before it
    np.testing.assert_array_equal(frames[1].samples[0], [0.5, 1.0, 1.5])


def test_a_time_tag_between_two_samples_is_refused_not_rounded(scripted_peer):
    peer = scripted_peer(SEG_OPEN + _batch(b"+3.125000000E-03\n"), timeout_s=30.0)  # 312.5 samples
    src = _segmented_source(peer)
    src.open()
    with pytest.raises(ConnectionError, match=r"segment 2 \(CHAN1\) starts, from the batch's first, 0.003125 s, "
                                              r"between two samples of the 100000 Hz clock"):
        src.read_frames(1.0)
    assert src.deframer_stats.corrupt == 1
    src.digitiser.link.close()


def test_the_gap_between_batches_is_measured_by_the_host_clock_and_flagged_estimated(scripted_peer):
    """Batch 2 completed 0.5 s (host clock) after batch 1; it spans 315 samples, so its first trigger
    came 50000 - 315 samples after batch 1's end: it starts at 315 + 49685 = 50000, flagged
    GAP_ESTIMATED (the instrument never said so)."""
    times = iter([10.0, 10.5])
    peer = scripted_peer(SEG_OPEN + _batch(b"3.12e-3\n") + _batch(b"3.12e-3\n"), timeout_s=30.0)
    src = _segmented_source(peer, clock=lambda: next(times))
    src.open()
    first, second = src.read_frames(1.0), src.read_frames(1.0)
    src.digitiser.link.close()
    peer.check()
    assert [(f.first_index, f.flags) for f in first] == [(0, 0), (312, 0)]
    assert [(f.first_index, f.flags) for f in second] == [(50_000, int(BlockFlags.GAP_ESTIMATED)), (50_312, 0)]


def test_an_instrument_closing_mid_block_is_a_lost_connection_not_a_timeout():
    """Review R1: the peer sends 4 of the 10 bytes its block announced and closes.  pyvisa-py reads
    the close as silence until its timeout; the driver then sees the closed socket and says so."""
    import socket
    import threading

    from hystbench.errors import ConnectionLost

    srv = socket.create_server(("127.0.0.1", 0))
    replies = {b"*IDN?": IDN, b"SYST:ERR?": OK, b"ACQ:SRAT?": b"100000\n", b"WAV:SOUR CHAN1;:WAV:PRE?": PRE5}

    def serve() -> None:
        conn, _ = srv.accept()
        with conn, conn.makefile("rb") as f:
            for line in f:
                if line.strip() == b"WAV:DATA?":
                    conn.sendall(b"#210\x01\x00\x02\x00")
                    return  # and close
                conn.sendall(replies.get(line.strip(), b""))

    t = threading.Thread(target=serve, daemon=True)
    t.start()
    link = VisaLink(f"TCPIP::127.0.0.1::{srv.getsockname()[1]}::SOCKET", 1.0)
    dig = ScpiDigitiser(link, sd.dialect("generic"), 100_000.0, max_points=1000)
    try:
        dig.open()
        with pytest.raises(ConnectionLost, match=r"'WAV:DATA\?' \(CHAN1\): the connection closed in the binary block "
                                                 r"after 4 bytes, waiting for 10 data bytes"):
            dig.fetch("CHAN1")
    finally:
        link.close()
        srv.close()
        t.join(5.0)
