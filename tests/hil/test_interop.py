"""Programs that are not ours can talk to the emulators: a raw socket speaking SCPI, pymodbus (and
mbpoll, if installed) reading the amplifier's register 0; and ``hystbench emulate`` standalone."""

import argparse
import json
import os
import selectors
import shutil
import signal
import socket
import subprocess
import sys

import pytest

from hystbench.cli import bench as commands_bench
from hystbench.deadline import Deadline
from hystbench.drivers.protocols.bench_config import load_bench_config
from hystbench.drivers.protocols.modbus_map import MODEL_ID
from hystbench.sim_backend.emulators.bench import EmulatedBench

from .conftest import bench_file


@pytest.fixture(scope="module")
def emu():
    with EmulatedBench(load_bench_config()) as e:
        yield e


def hostport(address):
    host, _, port = address.rpartition(":")
    return host, int(port)


def scpi_idn(address):
    with socket.create_connection(hostport(address), timeout=2.0) as s:
        s.settimeout(2.0)
        s.sendall(b"*IDN?\n")
        buf = b""
        while not buf.endswith(b"\n"):
            chunk = s.recv(256)
            assert chunk, "connection closed before a reply"
            buf += chunk
    return buf.decode()


def test_raw_socket_scpi(emu):
    address = emu.addresses["signal_generator"]["scpi_tcp"]
    assert address.startswith("127.0.0.1:")
    assert scpi_idn(address) == "HYSTBENCH,SIMGEN-1,0001,1.0\n"


def test_pymodbus_client_reads_register_0_over_tcp_and_rtu(emu):
    from pymodbus.client import ModbusSerialClient, ModbusTcpClient

    a = emu.addresses["current_amplifier"]
    host, port = hostport(a["modbus_tcp"])
    client = ModbusTcpClient(host, port=port, timeout=2, retries=0)
    try:
        assert client.connect()
        rr = client.read_holding_registers(0, count=1, device_id=a["unit"])
        assert not rr.isError() and rr.registers == [MODEL_ID]
    finally:
        client.close()
    client = ModbusSerialClient(a["modbus_rtu"], baudrate=19200, timeout=2, retries=0)
    try:
        assert client.connect()
        rr = client.read_holding_registers(0, count=2, device_id=a["unit"])
        assert not rr.isError() and rr.registers[0] == MODEL_ID
    finally:
        client.close()


@pytest.mark.skipif(shutil.which("mbpoll") is None, reason="mbpoll is not installed")
def test_mbpoll_reads_register_0(emu):
    a = emu.addresses["current_amplifier"]
    host, port = hostport(a["modbus_tcp"])
    # mbpoll's usual 1-based reference 1 is holding register address 0 (40001)
    out = subprocess.run(["mbpoll", "-m", "tcp", "-a", str(a["unit"]), "-r", "1", "-c", "1", "-1",
                          "-p", str(port), host], capture_output=True, text=True, timeout=10)
    assert f"{MODEL_ID}" in out.stdout, out.stdout + out.stderr


def first_line(proc, timeout_s):
    sel = selectors.DefaultSelector()
    sel.register(proc.stdout, selectors.EVENT_READ)
    deadline = Deadline(timeout_s)
    buf = b""
    while b"\n" not in buf:
        assert not deadline.expired, "no first line in time"
        if sel.select(deadline.left()):
            chunk = os.read(proc.stdout.fileno(), 4096)
            assert chunk, "emulate exited early"
            buf += chunk
    return buf.split(b"\n", 1)[0].decode()


def test_emulate_command_prints_addresses_then_runs_until_sigterm(tmp_path):
    cmd = [sys.executable, "-m", "hystbench", "emulate", "--config",
           str(bench_file(tmp_path))]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    try:
        where = json.loads(first_line(proc, 30.0))
        assert where["signal_generator"]["scpi_tcp"].startswith("127.0.0.1:")
        assert where["current_amplifier"]["modbus_tcp"].startswith("127.0.0.1:")
        assert where["current_amplifier"]["unit"] == 1
        assert where["charge_amplifier"]["serial"].startswith("/dev/pts/")
        assert where["flux_integrator"]["can_channel"]
        assert scpi_idn(where["signal_generator"]["scpi_tcp"]).startswith("HYSTBENCH,")
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=10) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(timeout=5)


def test_emulate_bad_config_exits_2_naming_file_and_key(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text(bench_file(tmp_path).read_text().replace("[sim]", "[sim]\nspeed = 3\n", 1))
    proc = subprocess.run([sys.executable, "-m", "hystbench", "emulate",
                           "--config", str(bad)], capture_output=True, text=True, timeout=20)
    assert proc.returncode == 2
    assert f"{bad} [sim]: unknown key 'speed'" in proc.stderr


def test_register_adds_the_emulate_subcommand():
    parser = argparse.ArgumentParser()
    commands_bench.register(parser.add_subparsers(dest="command"))
    args = parser.parse_args(["emulate", "--config", "x.toml"])
    assert args.func is commands_bench.cmd_emulate and args.config == "x.toml"


def test_cli_wiring_when_the_lead_has_added_it():
    from hystbench.cli import main as cli

    try:
        args = cli.build_parser().parse_args(["emulate", "--config", "x.toml"])
    except SystemExit:
        pytest.skip("hystbench.cli.main does not call commands_bench.register(sub) yet")
    assert args.func is commands_bench.cmd_emulate
