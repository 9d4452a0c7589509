"""The demo's bench parts: the live sweep is started through ctl's control path (no autostart),
and a failing bench part says why, leaves none of its (or an earlier run's) files behind, and lets
the demo go on."""

from pathlib import Path

from hystbench.reports import demo
from hystbench.reports.demo import demo_sweeps
from hystbench.reports.demo_live import demo_live
from hystbench.errors import InstrumentError


def test_live_sweep_is_commanded_over_zenoh_and_keeps_only_this_runs_log(tmp_path: Path) -> None:
    out = tmp_path / "live"
    out.mkdir()
    (out / "demo-20000101-000000-0001.mcap").write_bytes(b"an earlier run")
    res = demo_live(out, seconds=3.0, source="sim")
    assert res["error"] is None, res["error"]
    assert "autostart" not in (out / "demo-daemon.toml").read_text()  # only a ctl start_sweep can sweep
    assert res["points"] == [80.0, 160.0, 320.0]  # the commanded sweep ran, point by point
    # estimates of its points (a busy machine may deliver too few samples for some): flux lags the
    # current by a few degrees (paper Fig. 10)
    assert res["hysteresis_deg"] and set(res["hysteresis_deg"]) <= {"80", "160", "320"}
    assert all(0 < d < 10 for d in res["hysteresis_deg"].values())
    assert sorted(p.name for p in out.glob("demo-*.mcap")) == sorted(Path(p).name for p in res["log"])
    assert len(res["log"]) == 1 and "live estimates" in res["summary"]


def test_a_refused_live_sweep_is_reported_and_leaves_nothing(tmp_path: Path) -> None:
    out = tmp_path / "live"
    out.mkdir()
    (out / "demo-20000101-000000-0001.mcap").write_bytes(b"an earlier run")
    res = demo_live(out, seconds=1.5, source="synthetic")  # precomputed sines take no commands
    assert "refused start_sweep" in res["error"] and "takes no commands" in res["error"]
    assert "live part failed" in res["summary"] and res["log"] == []
    assert not out.exists()


def test_failing_driver_sweeps_are_reported_and_their_files_removed(tmp_path: Path, monkeypatch) -> None:
    """The bench too slow to keep up (the message Bench.acquire raises), injected at the acquisition:
    a real slow machine cannot be summoned on demand."""
    (tmp_path / "sweeps" / "ecore").mkdir(parents=True)
    (tmp_path / "sweeps" / "ecore" / "old.csv").write_text("t,i\n")
    (tmp_path / "summary.json").write_text("{}")
    (tmp_path / "ecore_pm_current_force.png").write_bytes(b"png")
    (tmp_path / "paper").mkdir()  # the offline part's folder is not this part's

    def too_slow(*args, **kwargs):
        raise InstrumentError("bench: only 0 of 10000 aligned samples within the timeout")

    monkeypatch.setattr(demo, "_sweep_through_drivers", too_slow)
    status, why = demo_sweeps(tmp_path)
    assert status == 0 and why == "bench: only 0 of 10000 aligned samples within the timeout"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["paper"]


def test_a_failure_is_printed_whole(tmp_path: Path) -> None:
    """The summary is rich markup: a '[source]' in the reason must be printed, not taken for a style."""
    import io

    from rich.console import Console

    res = demo_live(tmp_path / "live", seconds=1.5, source="nonsense")
    buf = io.StringIO()
    Console(file=buf, width=300).print(res["summary"])
    assert "[source] kind: must be one of bench, sim, synthetic" in buf.getvalue()
    assert not (tmp_path / "live").exists()
