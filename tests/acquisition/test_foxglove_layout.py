"""The shipped Foxglove layout is the generated one, is installed with the package, and every topic
it plots is one the daemon's live view serves (or one of the layout's own user scripts)."""

from __future__ import annotations

import json
import re
import tomllib

from hystbench.formats.mcaplog.schemas import SCHEMAS
from hystbench.reports.foxglove_layout import BANDS_TOPIC, LAYOUT_PATH, STATUS_LOG_TOPIC, main, render
from hystbench.service.foxglove_live import LIVE_TOPICS, PLOT_PREFIX, PLOT_SAMPLES

from .conftest import ROOT


def test_the_shipped_layout_is_the_generated_one() -> None:
    assert LAYOUT_PATH.read_text(encoding="utf-8") == render(), \
        "hystbench/config/foxglove_layout.json is stale: run python -m hystbench.reports.foxglove_layout"
    assert main(["--check"]) == 0


def test_the_layout_is_package_data() -> None:
    data = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["tool"]["setuptools"]["package-data"]
    assert any(p.endswith("*.json") for p in data["hystbench.config"])


def test_every_topic_it_reads_is_served() -> None:
    text = LAYOUT_PATH.read_text(encoding="utf-8")
    layout = json.loads(text)
    scripts = layout["userScripts"]
    outputs = {re.search(r'export const output = "([^"]+)"', s["sourceCode"]).group(1) for s in scripts.values()}
    assert outputs == {BANDS_TOPIC, STATUS_LOG_TOPIC}
    inputs = {t for s in scripts.values() for t in re.findall(r'"(/[a-z_/]+)"', s["sourceCode"].split("export const inputs", 1)[1].split(";")[0])}
    assert inputs == {"/estimate", "/status"} <= set(LIVE_TOPICS) & set(SCHEMAS)
    served = set(LIVE_TOPICS) | {PLOT_SAMPLES} | {PLOT_PREFIX + c for c in ("current_A", "force_N")} | outputs
    read = set(re.findall(r'"(?:value|topicPath|topicToRender)": "(/[A-Za-z_/]+)', text))
    assert read and {t.rsplit(".", 1)[0] for t in read} <= served, read
    for key in ("hysteresis", "instrument", "total"):  # the three delays, each with its two bounds
        for part in ("delay_us", "low_us", "high_us"):
            assert f'"{BANDS_TOPIC}.{key}.{part}"' in text
    assert '"/plot/samples.current_A"' in text and '"/plot/samples.force_N"' in text  # the loop


def test_a_benchs_fleet_layout_reads_only_what_the_fleet_view_serves_for_it(tmp_path) -> None:
    """``--bench bench3 --out F``: the same delays and status log, on ``/bench3/estimate`` and
    ``/bench3/status`` (what ``hystbench router --foxglove`` makes of hystbench/bench3/...), and no
    ``/plot`` panel, which the fleet view does not carry; the shipped file is left as it is."""
    shipped = LAYOUT_PATH.read_text(encoding="utf-8")
    out = tmp_path / "bench3.json"
    assert main(["--bench", "bench3", "--out", str(out)]) == 0
    assert LAYOUT_PATH.read_text(encoding="utf-8") == shipped
    text = out.read_text(encoding="utf-8")
    scripts = json.loads(text)["userScripts"]
    inputs = {t for s in scripts.values() for t in re.findall(r'"(/[a-z0-9_/]+)"', s["sourceCode"].split("export const inputs", 1)[1].split(";")[0])}
    assert inputs == {"/bench3/estimate", "/bench3/status"}
    read = {t.rsplit(".", 1)[0] for t in re.findall(r'"(?:value|topicPath|topicToRender)": "(/[A-Za-z0-9_/]+)', text)}
    assert read == {BANDS_TOPIC, STATUS_LOG_TOPIC, "/bench3/status"}, read
    assert "/plot" not in text
    assert main(["--bench", "bench3", "--out", str(out)]) == 2  # exists: --overwrite, as every output
    assert main(["--bench", "a/b", "--out", str(tmp_path / "x.json")]) == 2 and not (tmp_path / "x.json").exists()
