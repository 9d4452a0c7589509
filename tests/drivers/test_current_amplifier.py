"""Current amplifier driver: byte-exact Modbus TCP (MBAP) and RTU (CRC) transcripts through pymodbus,
exception responses, and the current budget on gain and limit writes."""

import pytest

from hystbench.drivers.current_amplifier import ModbusCurrentAmplifier, ModbusError
from hystbench.drivers.protocols.modbus_map import MODEL_ID, REGISTERS, crc16
from hystbench.drivers.safety import CurrentBudget, SafetyLimitError
from hystbench.errors import ConfigError, InstrumentTimeout, ProtocolError

h = bytes.fromhex


def tcp(tid: int, pdu: str) -> bytes:
    body = h(pdu)
    return tid.to_bytes(2, "big") + b"\x00\x00" + (len(body) + 1).to_bytes(2, "big") + b"\x01" + body


def amp(peer, **kw):
    """The driver on the scripted peer, with a generous timeout unless a test waits for it to pass."""
    host, port = peer.address.split(":")
    return ModbusCurrentAmplifier(budget=kw.pop("budget", CurrentBudget(2.0, 0.5)), host=host, port=int(port),
                                  timeout_s=kw.pop("timeout_s", 10.0), **kw)


OPEN_TCP = [
    (tcp(1, "03 0000 0002"), tcp(1, "03 04 4841 0102")),  # model id, firmware
    (tcp(2, "03 0005 0001"), tcp(2, "03 02 01F4")),  # gain 500 mA/V
]
CLOSE_TCP = lambda t: [(tcp(t, "06 0002 0000"), tcp(t, "06 0002 0000")),  # control = 0: disable
                       (tcp(t + 1, "03 0003 0001"), tcp(t + 1, "03 02 0000"))]  # status: not enabled


def test_modbus_tcp_open_configure_enable_close_byte_exact(scripted_peer):
    peer = scripted_peer(OPEN_TCP + [
        (tcp(3, "06 0005 0190"), tcp(3, "06 0005 0190")),  # gain 0.4 A/V
        (tcp(4, "03 0005 0001"), tcp(4, "03 02 0190")),  # read back
        (tcp(5, "06 0006 05DC"), tcp(5, "06 0006 05DC")),  # limit 1.5 A
        (tcp(6, "06 0007 01F4"), tcp(6, "06 0007 01F4")),  # watchdog 0.5 s
        (tcp(7, "06 0002 0001"), tcp(7, "06 0002 0001")),  # enable
        (tcp(8, "03 0002 0009"), tcp(8, "03 12 0001 0005 0000 0190 05DC 01F4 FF9C 01C2 09C4")),
    ] + CLOSE_TCP(9))
    budget = CurrentBudget(2.0, 0.5)
    with amp(peer, budget=budget) as a:
        assert a.firmware == "1.2"
        a.configure(gain_a_per_v=0.4, current_limit_a=1.5, watchdog_s=0.5, enabled=True)
        assert budget.gain_a_per_v == 0.4
        st = a.read_status()
        assert st.ok and st.values == {"enabled": True, "gain_a_per_v": 0.4, "current_limit_a": 1.5,
                                       "watchdog_s": 0.5, "current_a": -0.1, "current_rms_a": 0.45,
                                       "temperature_c": 25.0}
    peer.check()


def test_exception_response_names_register_and_exception(scripted_peer):
    peer = scripted_peer(OPEN_TCP + [(tcp(3, "06 0006 05DC"), tcp(3, "86 03"))] + CLOSE_TCP(4))
    with amp(peer) as a:
        with pytest.raises(ModbusError, match=r"write current_limit \(register 6\) = 1500 -> "
                                              r"Modbus exception 3 \(ILLEGAL DATA VALUE\)") as info:
            a.set_current_limit(1.5)
        assert info.value.code == 3
    peer.check()


def test_fault_bits_are_reported(scripted_peer):
    peer = scripted_peer(OPEN_TCP + [
        (tcp(3, "03 0002 0009"), tcp(3, "03 12 0000 0002 0006 01F4 07D0 0000 0000 0000 1F40")),
    ] + CLOSE_TCP(4))
    with amp(peer) as a:
        st = a.status()
        assert not st.ok and st.faults == ("OVERTEMP", "WATCHDOG") and st.values["temperature_c"] == 80.0
    peer.check()


def test_wrong_model_is_refused(scripted_peer):
    peer = scripted_peer([(tcp(1, "03 0000 0002"), tcp(1, "03 04 1234 0102"))])
    with pytest.raises(ProtocolError, match="register 0 .model id. is 0x1234, expected 0x4841"):
        amp(peer).open()
    peer.check()


def test_budget_and_range_refusals_send_nothing(scripted_peer):
    peer = scripted_peer(OPEN_TCP + CLOSE_TCP(3))
    budget = CurrentBudget(1.0, 0.5)
    budget.commit_command(1.5)  # the generator peaks at 1.5 V
    with amp(peer, budget=budget) as a:
        with pytest.raises(SafetyLimitError, match=r"1.5 V x 0.8 A/V = 1.2 A exceeds the command limit 0.95 A"):
            a.set_gain(0.8)
        with pytest.raises(SafetyLimitError, match="current limit 1.5 A exceeds"):
            a.set_current_limit(1.5)
        with pytest.raises(ConfigError, match="register 7"):
            a.set_watchdog(100.0)
        with pytest.raises(ConfigError, match="read-only"):
            a.write("status", 1)
    peer.check()


def test_gain_found_at_open_beyond_the_budget_is_refused(scripted_peer):
    peer = scripted_peer([(tcp(1, "03 0000 0002"), tcp(1, "03 04 4841 0102")),
                          (tcp(2, "03 0005 0001"), tcp(2, "03 02 2710"))])  # 10 A/V
    budget = CurrentBudget(2.0, 0.5)
    budget.commit_command(1.0)
    with pytest.raises(SafetyLimitError, match="gain as found at open"):
        amp(peer, budget=budget).open()


def test_no_reply_is_a_timeout(scripted_peer):
    peer = scripted_peer(OPEN_TCP + [(tcp(3, "03 0005 0001"), None)])
    a = amp(peer, timeout_s=0.5).open()
    with pytest.raises(InstrumentTimeout, match=r"current_amplifier: no answer to 'read 1 register\(s\) from 5"):
        a.read("gain")
    a._open = False  # the scripted peer is done: do not disable on close
    a._close_hook()
    peer.check()


def rtu(pdu: str) -> bytes:
    body = b"\x01" + h(pdu)
    return body + crc16(body).to_bytes(2, "little")


def test_modbus_rtu_frames_byte_exact(scripted_peer):
    assert rtu("03 0000 0002") == h("01 03 0000 0002 C40B")  # the textbook frame: CRC checked independently
    peer = scripted_peer([
        (rtu("03 0000 0002"), rtu("03 04 4841 0102")),
        (rtu("03 0005 0001"), rtu("03 02 01F4")),
        (rtu("06 0002 0001"), rtu("06 0002 0001")),
        (rtu("06 0002 0000"), rtu("06 0002 0000")),
        (rtu("03 0003 0001"), rtu("03 02 0000")),
    ])
    a = ModbusCurrentAmplifier(budget=CurrentBudget(2.0, 0.5), serial_port=peer.url, baudrate=115200, timeout_s=10.0)
    with a:
        a.enable()
    peer.check()


def test_register_map_is_consistent():
    addresses = [r.address for r in REGISTERS.values()]
    assert addresses == sorted(addresses) == list(range(len(addresses)))
    assert REGISTERS["model_id"].address == 0 and MODEL_ID == 0x4841
    assert REGISTERS["current"].to_si(0xFF9C) == pytest.approx(-0.1)
