"""The NI-DAQmx backend against a recorded transcript of nidaqmx calls.

NI's nidaqmx package needs NI's C driver even for its simulated devices, and the driver is not
on this machine, so the package's own simulated-device path cannot run here.  Instead a fake
``nidaqmx`` is put at the module boundary (``sys.modules``): it checks every call the backend
makes against the transcript below, in order, and replays the samples a card would return (each
sample's value is its own index, so a sample moved, repeated or invented is seen).  The real
package is used for what works without the driver: its error when NI-DAQmx is missing."""

from __future__ import annotations

import sys
import types
from enum import Enum

import numpy as np
import pytest

from hystbench.drivers.base import Backoff
from hystbench.drivers.daqmx import DaqmxFrameSource
from hystbench.drivers.stream import SampleStream
from hystbench.errors import ConfigError

CHANNELS = ["Dev1/ai0", "Dev1/ai1", "Dev1/ai2", "Dev1/ai3"]


class AcquisitionType(Enum):
    CONTINUOUS = 10123


class OverwriteMode(Enum):
    OVERWRITE_UNREAD_SAMPLES = 10252


class ReadRelativeTo(Enum):
    FIRST_SAMPLE = 10424


class DaqError(Exception):
    def __init__(self, message: str = "", error_code: int = 0) -> None:
        super().__init__(message)
        self.error_code = error_code


class DaqNotFoundError(Exception):
    pass


class Card:
    """The transcript: what the backend must call, in order, and what the card answers."""

    def __init__(self, script: list[tuple]) -> None:
        self.script, self.step = list(script), 0

    def call(self, *call):
        assert self.step < len(self.script), f"call {call} after the end of the transcript"
        want, answer = self.script[self.step]
        if want == ("close",) and call == ("total_samp_per_chan_acquired",):
            return self.script[self.step - 3][1]  # the reader polls on until closed: nothing new acquired
        assert call == want, f"step {self.step}: expected {want}, got {call}"
        self.step += 1
        return answer


def fake_nidaqmx(card: Card) -> dict[str, types.ModuleType]:
    class InStream:
        @property
        def total_samp_per_chan_acquired(self):
            return card.call("total_samp_per_chan_acquired")

        def __setattr__(self, name, value):
            card.call("in_stream." + name, value)

    class Reader:
        def __init__(self, stream):
            card.call("AnalogMultiChannelReader")

        def read_many_sample(self, data, number_of_samples_per_channel, timeout):
            first = card.call("read_many_sample", data.shape, number_of_samples_per_channel)
            if isinstance(first, Exception):
                raise first
            data[:] = np.arange(first, first + data.shape[1]) + 1e6 * np.arange(data.shape[0])[:, None]
            return data.shape[1]

    class Task:
        def __init__(self):
            card.call("Task")
            self.in_stream = InStream()
            self.ai_channels = types.SimpleNamespace(
                add_ai_voltage_chan=lambda ch, min_val, max_val: card.call("add_ai_voltage_chan", ch, min_val, max_val))
            self.timing = types.SimpleNamespace(
                cfg_samp_clk_timing=lambda rate, source, sample_mode, samps_per_chan:
                card.call("cfg_samp_clk_timing", rate, source, sample_mode.name, samps_per_chan))
            self.triggers = types.SimpleNamespace(start_trigger=types.SimpleNamespace(
                cfg_dig_edge_start_trig=lambda src: card.call("cfg_dig_edge_start_trig", src)))

        def start(self):
            card.call("start")

        def close(self):
            card.call("close")

    root = types.ModuleType("nidaqmx")
    root.Task = Task
    const = types.ModuleType("nidaqmx.constants")
    const.AcquisitionType, const.OverwriteMode, const.ReadRelativeTo = AcquisitionType, OverwriteMode, ReadRelativeTo
    readers = types.ModuleType("nidaqmx.stream_readers")
    readers.AnalogMultiChannelReader = Reader
    errors = types.ModuleType("nidaqmx.errors")
    errors.DaqError, errors.DaqNotFoundError = DaqError, DaqNotFoundError
    return {"nidaqmx": root, "nidaqmx.constants": const, "nidaqmx.stream_readers": readers, "nidaqmx.errors": errors}


OPEN = [
    (("Task",), None),
    *[(("add_ai_voltage_chan", ch, -10.0, 10.0), None) for ch in CHANNELS],
    (("cfg_samp_clk_timing", 1000.0, "/Dev1/PFI0", "CONTINUOUS", 1000), None),
    (("cfg_dig_edge_start_trig", "/Dev1/PFI1"), None),
    (("in_stream.over_write", OverwriteMode.OVERWRITE_UNREAD_SAMPLES), None),
    (("in_stream.relative_to", ReadRelativeTo.FIRST_SAMPLE), None),
    (("AnalogMultiChannelReader",), None),
    (("start",), None),
]


def two_blocks(monkeypatch, card: Card, *, scale: dict | None = None, clock=None, backoff: Backoff | None = None):
    """The transcript ``card`` played through the real source and SampleStream (the fake package in
    place of nidaqmx): the stream's first two blocks, the source and the stream, every call checked made."""
    for name, mod in fake_nidaqmx(card).items():
        monkeypatch.setitem(sys.modules, name, mod)
    src = DaqmxFrameSource(CHANNELS, 1000.0, clock_source="/Dev1/PFI0", trigger_source="/Dev1/PFI1", buffer_s=1.0,
                           poll_s=0.001, **({} if clock is None else {"clock": clock}))
    stream = SampleStream("digitiser", src, ["current_A", "force_N", "flux_Wb", "command_V"], 1000.0,
                          scale=scale, stall_timeout_s=60.0,
                          **({} if backoff is None else {"backoff": backoff})).start()
    try:
        a = stream.read(timeout_s=30.0)
        b = stream.read(timeout_s=30.0)
    finally:
        stream.close()
    assert card.step == len(card.script), f"only {card.step} of {len(card.script)} calls made"
    return a, b, src, stream


def test_continuous_acquisition_reads_by_absolute_index_and_skips_overwritten_samples(monkeypatch):
    card = Card(OPEN + [
        (("total_samp_per_chan_acquired",), 300),  # 300 acquired: read them all from index 0
        (("in_stream.offset", 0), None), (("read_many_sample", (4, 300), 300), 0),
        (("total_samp_per_chan_acquired",), 1500),  # 1500 acquired, the buffer holds 1000: 300..499 are gone
        (("in_stream.offset", 500), None), (("read_many_sample", (4, 1000), 1000), 500),
        (("close",), None),  # (polls until then answer 1500 again: nothing new, no frame)
    ])
    a, b, src, _ = two_blocks(monkeypatch, card, scale={"force_N": 50.0})
    assert (a.first_index, a.n, a.gap_samples) == (0, 300, 0)
    assert (b.first_index, b.n, b.gap_samples) == (500, 1000, 200) and src.skipped == 200
    np.testing.assert_array_equal(a.channels["current_A"], np.arange(0, 300))
    np.testing.assert_array_equal(b.channels["current_A"], np.arange(500, 1500))
    np.testing.assert_array_equal(b.channels["force_N"], 50.0 * (1e6 + np.arange(500, 1500)))


def test_a_missing_nidaqmx_package_says_what_to_install(monkeypatch):
    monkeypatch.setitem(sys.modules, "nidaqmx", None)  # import nidaqmx now raises ImportError
    with pytest.raises(ConfigError, match=r'kind = "daqmx" needs the nidaqmx package.*pip install hystbench\[nidaqmx\]'):
        DaqmxFrameSource(CHANNELS, 1000.0).open()


def test_the_real_package_without_nis_driver_says_what_to_install():
    pytest.importorskip("nidaqmx")
    from nidaqmx._lib import lib_importer

    try:
        lib_importer.windll if sys.platform == "win32" else lib_importer.cdll
        pytest.skip("NI-DAQmx is installed here")
    except Exception:
        pass
    with pytest.raises(ConfigError, match=r"NI-DAQmx \(NI's driver\) is not installed: pip install hystbench\[nidaqmx\]"):
        DaqmxFrameSource(CHANNELS, 1000.0).open()


def test_samples_overwritten_while_being_read_are_an_exact_gap_not_a_new_task(monkeypatch):
    """Review R1: the card overwrites the oldest unread samples while they are read (DAQmx error
    -200279).  The task keeps running, so the next read skips to what the buffer still holds: an
    exact gap.  Reopening instead would restart the indices at the new task's first sample, and the
    stream would drop everything up to the old index as stale."""
    gone = DaqError("Attempted to read samples that are no longer available.", error_code=-200279)
    card = Card(OPEN + [
        (("total_samp_per_chan_acquired",), 300),
        (("in_stream.offset", 0), None), (("read_many_sample", (4, 300), 300), 0),
        (("total_samp_per_chan_acquired",), 1200),  # 300..1199 asked for, overwritten during the read
        (("in_stream.offset", 300), None), (("read_many_sample", (4, 900), 900), gone),
        (("total_samp_per_chan_acquired",), 1600),  # the buffer holds 600..1599: 300..599 are gone
        (("in_stream.offset", 600), None), (("read_many_sample", (4, 1000), 1000), 600),
        (("close",), None),
    ])
    a, b, src, stream = two_blocks(monkeypatch, card)
    assert (a.first_index, a.n, a.gap_samples) == (0, 300, 0)
    assert (b.first_index, b.n, b.gap_samples) == (600, 1000, 300) and src.skipped == 300
    assert stream.stats.reconnects == 0
    np.testing.assert_array_equal(b.channels["current_A"], np.arange(600, 1600))


def test_the_install_error_names_the_bench_file_that_asked_for_daqmx(monkeypatch, tmp_path):
    """Review R1: the error a user fixes names the file and table (the project's rule for bad input)."""
    from hystbench.drivers.digitiser import _source_class
    from hystbench.drivers.protocols.bench_config import DEFAULT_BENCH, load_bench_config

    text = (DEFAULT_BENCH.parent / "bench_digitiser.toml").read_text()
    table = ('[digitiser]\nbackend = "hardware"\nkind = "daqmx"\nchannels = { current_A = "Dev1/ai0", '
             'force_N = "Dev1/ai1", flux_Wb = "Dev1/ai2", command_V = "Dev1/ai3" }\n')
    path = tmp_path / "my_bench.toml"
    path.write_text(text.split("\n[digitiser]\n")[0] + "\n" + table)
    bench = load_bench_config(path)
    monkeypatch.setitem(sys.modules, "nidaqmx", None)
    src = _source_class("daqmx").from_config(bench.digitiser, bench)
    with pytest.raises(ConfigError, match=rf'^{str(path)!s} \[digitiser\] kind = "daqmx" needs the nidaqmx package'):
        src.open()


def test_any_other_read_error_starts_a_new_epoch_after_an_estimated_gap_not_indices_from_zero(monkeypatch):
    """Review R1: a read error other than -200279 reopens the task, which counts from its own first
    sample again: read as indices from 0, the stream dropped everything as stale, the loss never
    reported.  The new task's samples now follow the old ones after the gap the host clock measured
    (last read at t = 1.0 s, new task at t = 1.5 s: 500 samples at 1 kHz), flagged as estimated."""
    from hystbench.blocks import BlockFlags

    lost = DaqError("Onboard device memory overflow.", error_code=-200361)
    card = Card(OPEN + [
        (("total_samp_per_chan_acquired",), 300),
        (("in_stream.offset", 0), None), (("read_many_sample", (4, 300), 300), 0),
        (("total_samp_per_chan_acquired",), 700),
        (("in_stream.offset", 300), None), (("read_many_sample", (4, 400), 400), lost),
        (("close",), None),  # the stream reopens: a new task
        *OPEN,
        (("total_samp_per_chan_acquired",), 200),
        (("in_stream.offset", 0), None), (("read_many_sample", (4, 200), 200), 0),
        (("close",), None),
    ])
    times = iter([1.0, 1.5, 2.0])
    a, b, src, stream = two_blocks(monkeypatch, card, clock=lambda: next(times),
                                   backoff=Backoff(initial_s=0.001, factor=1.0, max_s=0.001, attempts=2))
    assert (a.first_index, a.n, a.gap_samples) == (0, 300, 0)
    assert (b.first_index, b.n, b.gap_samples) == (800, 200, 500)
    assert b.flags & BlockFlags.GAP and b.flags & BlockFlags.GAP_ESTIMATED
    assert stream.stats.reconnects == 1
    assert (stream.stats.estimated_gaps, stream.stats.estimated_gap_samples) == (1, 500)
    np.testing.assert_array_equal(b.channels["current_A"], np.arange(0, 200))  # the new task's own samples
