"""Charge amplifier driver: byte-exact ASCII transcripts (CR-terminated), E<nn> replies, and the one
mnemonic table both ends use."""

import pytest

from hystbench.drivers.charge_amplifier import ChargeAmpError, ChargeAmplifier
from hystbench.drivers.protocols import charge_amp as ca
from hystbench.errors import ConfigError, InstrumentTimeout, ProtocolError

OPEN = [(b"ID?\r", b"5070A,SN4711,2.0\r"), (b"SE?\r", b"1\r"), (b"SC?\r", b"100\r"),
        (b"TC?\r", b"LONG\r"), (b"LP?\r", b"0\r")]


def amp(peer, **kw):
    """The driver on the scripted peer, with a generous timeout unless a test waits for it to pass."""
    return ChargeAmplifier(peer.url, timeout_s=kw.pop("timeout_s", 10.0), **kw)


def test_open_configure_operate_status_byte_exact(scripted_peer):
    peer = scripted_peer(OPEN + [
        (b"SE 3.5\r", b"OK\r"), (b"SC 50\r", b"OK\r"), (b"TC MEDIUM\r", b"OK\r"), (b"LP 10000\r", b"OK\r"),
        (b"OP\r", b"OK\r"),
        (b"ST?\r", b"3\r"),
        (b"RS\r", b"OK\r"),
    ])
    with amp(peer) as c:
        assert c.identity == "5070A,SN4711,2.0"
        assert c.settings == {"sensitivity_pc_per_n": 1.0, "scale_n_per_v": 100.0, "time_constant": "LONG",
                              "lowpass_hz": 0.0}
        c.configure(sensitivity_pc_per_n=3.5, scale_n_per_v=50, time_constant="medium", lowpass_hz=10e3)
        c.operate()
        st = c.status()
        assert not st.ok and st.faults == ("OVERLOAD",) and st.values["operate"]
        c.reset()
    peer.check()


def test_error_reply_names_the_command(scripted_peer):
    peer = scripted_peer(OPEN + [(b"TC SHORT\r", b"E04\r"), (b"XX?\r", b"E01\r")])
    with amp(peer) as c:
        with pytest.raises(ChargeAmpError, match=r"'TC SHORT' -> E04 \(not allowed while operating\)"):
            c.set("time_constant", "SHORT")
        assert c.settings["time_constant"] == "LONG"
        c.link.write(b"XX?\r")  # a command outside the table, sent raw: the amplifier says E01
        assert ca.parse_reply_error(c.link.read_line().decode()) == 1
    peer.check()


def test_table_refusals_send_nothing(scripted_peer):
    peer = scripted_peer(OPEN)
    with amp(peer) as c:
        with pytest.raises(ConfigError, match="lowpass_hz"):
            c.set("lowpass_hz", 2e5)
        with pytest.raises(ConfigError, match="time_constant"):
            c.set("time_constant", "FOREVER")
        with pytest.raises(ConfigError, match="no setting 'range'"):
            c.configure(range=3)
    peer.check()


def test_missing_reply_is_a_timeout_naming_the_command(scripted_peer):
    peer = scripted_peer(OPEN + [(b"SC?\r", None)])
    with amp(peer, timeout_s=0.5) as c:
        with pytest.raises(InstrumentTimeout, match=r"charge_amplifier: no answer to 'SC\?' within 0.5 s"):
            c.query("scale_n_per_v")
    peer.check()


def test_garbled_reply_is_a_protocol_error(scripted_peer):
    peer = scripted_peer(OPEN + [(b"SE?\r", b"\x07\x13?\r")])
    with amp(peer) as c:
        with pytest.raises(ProtocolError, match=r"unexpected answer to 'SE\?'"):
            c.query("sensitivity_pc_per_n")
    peer.check()


def test_every_mnemonic_lives_in_the_one_table():
    assert set(ca.COMMANDS) == {"identity", "reset", "operate", "mode", "sensitivity_pc_per_n", "scale_n_per_v",
                                "time_constant", "lowpass_hz", "status"}
    assert ca.COMMANDS["scale_n_per_v"].set_command(50) == b"SC 50\r"
