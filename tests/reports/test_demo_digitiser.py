"""The demo with its samples from the emulated SCPI digitiser (``hystbench demo --source
digitiser``, issue 15): the daemon's service records and estimates through pyvisa-py, and the
driver sweeps take their recordings from it."""

from pathlib import Path

import numpy as np

from hystbench.analysis.method import measure_delays
from hystbench.cli.main import build_parser
from hystbench.config import CONFIG_DIR
from hystbench.reports import demo
from hystbench.reports.demo_live import demo_live

DIGITISER_BENCH = CONFIG_DIR / "bench_digitiser.toml"


def test_the_daemon_records_and_estimates_from_the_digitiser(tmp_path: Path) -> None:
    out = tmp_path / "live"
    res = demo_live(out, seconds=3.0, source="bench", bench_file=DIGITISER_BENCH)
    assert res["error"] is None, res["error"]
    assert f'bench_file = "{DIGITISER_BENCH.as_posix()}"' in (out / "demo-daemon.toml").read_text()
    assert res["points"] == [80.0, 160.0, 320.0]
    # flux lags the current by a few degrees (paper Fig. 10), as from the framed streams
    assert res["hysteresis_deg"] and all(0 < d < 10 for d in res["hysteresis_deg"].values())
    assert len(res["log"]) == 1


def test_a_driver_sweep_point_through_the_digitiser(tmp_path: Path) -> None:
    recs = demo._sweep_through_drivers("ecore_pm", 1.4, (320.0,), lambda: None, DIGITISER_BENCH)
    assert len(recs) == 1
    rec = recs[0]
    assert set(rec.channels) == {"current_A", "force_N", "flux_Wb", "command_V"}
    n = int(round(demo.DURATION_S * rec.fs_hz))
    assert all(x.size == n for x in rec.channels.values())
    # 1.4 A-pp (peak 0.7 A) through the digitiser's 16-bit codes of 0.2 A/V x 10/32768 V = 61 uA
    assert abs(np.max(rec.channels["current_A"]) - 0.7) < 0.01 and abs(np.min(rec.channels["current_A"]) + 0.7) < 0.01
    assert np.all(np.abs(rec.channels["current_A"] / (0.2 * 10 / 32768) % 1 - 0.5) > 0.5 - 1e-6)  # whole codes
    assert measure_delays(rec).delays_s["hysteresis"] > 0
    assert rec.metadata["source"].endswith("samples from the emulated SCPI digitiser (generic dialect, pyvisa-py)")


def test_the_demo_command_takes_the_source() -> None:
    assert build_parser().parse_args(["demo", "--source", "digitiser"]).source == "digitiser"
    assert build_parser().parse_args(["demo"]).source == "streams"


def test_the_demo_names_the_sample_source_it_runs_on() -> None:
    """Review R1: the header said 'a sweep through the emulated instruments' with --source digitiser."""
    assert demo.sample_source(DIGITISER_BENCH) == "the emulated SCPI digitiser (generic dialect, pyvisa-py)"
    assert demo.sample_source() == "the emulated instruments' own streams"
