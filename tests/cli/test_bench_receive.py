"""``python -m benchmarks receive``: every stream kind's path delivers every sample it was fed (the run
raises otherwise), the figures are consistent with each other, and bad options are one line, exit 2."""

from __future__ import annotations

import json

import pytest

from benchmarks import bench_receive
from benchmarks.__main__ import main


def test_a_short_run_reports_every_kind_with_consistent_figures(capsys):
    main(["receive", "--seconds", "0.02", "--repeats", "1", "--json"])
    result = json.loads(capsys.readouterr().out)
    kinds = {k["kind"]: k for k in result["kinds"]}
    assert set(kinds) == {"tcp", "serial_cobs", "canfd", "canfd_bus", "canfd_recv_only"}
    for k in kinds.values():
        assert k["samples"] > 0 and k["cpu_s"] > 0
        assert k["x_of_100kSps"] == pytest.approx(k["samples"] / k["cpu_s"] / 100_000.0)
    assert {k for k, v in kinds.items() if v["judged"]} == {"tcp", "serial_cobs", "canfd"}
    assert result["passed"] == all(kinds[k]["x_of_100kSps"] >= 50.0 for k in ("tcp", "serial_cobs", "canfd"))


def test_a_signal_like_the_instruments_has_the_zero_bytes_cobs_stuffs():
    """ADC-quantised float32: a large share of zero bytes, which is what makes COBS work per byte."""
    raw = bench_receive._signal(10_000).tobytes()
    assert raw.count(0) > 0.15 * len(raw)  # 19 % here; the emulated charge amplifier's stream: 21 %


@pytest.mark.parametrize("args", [["--seconds", "0"], ["--repeats", "0"]])
def test_bad_options_are_refused(args, capsys):
    with pytest.raises(SystemExit) as exit_:
        main(["receive", *args])
    assert exit_.value.code == 2
    assert "--seconds must be > 0" in capsys.readouterr().err
