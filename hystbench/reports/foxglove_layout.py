"""The shipped Foxglove layout (hystbench/config/foxglove_layout.json), built with foxglove-sdk's
layout types so it is a layout Foxglove's own schema describes (docs/foxglove.md says how to open it).

    python -m hystbench.reports.foxglove_layout            # rewrite hystbench/config/foxglove_layout.json
    python -m hystbench.reports.foxglove_layout --check    # exit 1 if the shipped file is out of date

What it shows, on the daemon's live view and (the delays and the status) on an MCAP log alike:

- the three delays (hysteresis, instrument, total) of each ``/estimate``, in microseconds, one plot
  each, with dashed lines at plus and minus one standard error (``delays_std_s``).  Foxglove's Plot
  panel draws no error bars, so a user script of the layout (``/foxglove_script/delay_bands``)
  turns each estimate into the delay and its two bounds;
- the current-force loop: ``/plot/samples.force_N`` against ``/plot/samples.current_A`` (the
  instantaneous pairs, live only), beside the current's and the force's envelopes (``min``/``max``
  of each ``/plot/<channel>`` bin) over the last 10 s;
- the status log: ``/status`` turned into ``foxglove.Log`` by a second user script (the Log panel
  reads only that schema), and the last status message whole.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

from .generated import generated_file_main

__all__ = ["layout", "LAYOUT_PATH", "main", "BANDS_TOPIC", "STATUS_LOG_TOPIC"]

LAYOUT_PATH = Path(__file__).resolve().parents[1] / "config" / "foxglove_layout.json"
COMMAND = "python -m hystbench.reports.foxglove_layout"
BANDS_TOPIC = "/foxglove_script/delay_bands"
STATUS_LOG_TOPIC = "/foxglove_script/status_log"
DELAYS = (("hysteresis", "flux behind current", "#1f77b4"), ("instrument", "force behind flux", "#2ca02c"),
          ("total", "force behind current", "#d62728"))

_BANDS_SCRIPT = f"""\
// Each estimate's three delays in microseconds with their one-standard-error bounds: the Plot
// panel draws no error bars, so the bounds are plotted as dashed lines. Refused windows (no
// delays) publish nothing.
import {{ Input }} from "./types";

export const inputs = ["/estimate"];
export const output = "{BANDS_TOPIC}";

type Band = {{ delay_us: number; low_us: number; high_us: number }};
type Output = {{ hysteresis: Band; instrument: Band; total: Band }};
type Delays = Record<string, number | null | undefined>;

function band(d: Delays, s: Delays, k: string): Band | undefined {{
  const v = d[k], e = s[k] ?? 0;
  if (v === null || v === undefined) return undefined;
  return {{ delay_us: v * 1e6, low_us: (v - e) * 1e6, high_us: (v + e) * 1e6 }};
}}

export default function script(event: Input<"/estimate">): Output | undefined {{
  const m = event.message as unknown as {{ delays_s?: Delays; delays_std_s?: Delays }};
  const d = m.delays_s ?? {{}}, s = m.delays_std_s ?? {{}};
  const h = band(d, s, "hysteresis"), i = band(d, s, "instrument"), t = band(d, s, "total");
  if (!h || !i || !t) return undefined;
  return {{ hysteresis: h, instrument: i, total: t }};
}}
"""

_STATUS_SCRIPT = f"""\
// The daemon's status messages (hystbench.Status) as foxglove.Log, the one schema the Log panel
// shows: level info/warning/error, the event as the name, the message and its other fields.
import {{ Input }} from "./types";
import {{ Log }} from "@foxglove/schemas";

export const inputs = ["/status"];
export const output = "{STATUS_LOG_TOPIC}";

const LEVELS: Record<string, number> = {{ info: 2, warning: 3, error: 4 }};

export default function script(event: Input<"/status">): Log {{
  const m = event.message as unknown as Record<string, unknown>;
  const rest: Record<string, unknown> = {{}};
  for (const k of Object.keys(m)) {{
    if (!["t_ns", "level", "event", "message"].includes(k)) rest[k] = m[k];
  }}
  const extra = Object.keys(rest).length > 0 ? " " + JSON.stringify(rest) : "";
  return {{
    timestamp: event.receiveTime,  // the message's t_ns: its log time
    level: (LEVELS[String(m.level)] ?? 0) as Log["level"],
    message: String(m.message ?? "") + extra,
    name: String(m.event ?? ""),
    file: "",
    line: 0,
  }};
}}
"""


def layout() -> dict[str, Any]:
    """The layout as Foxglove's layout JSON (a dict)."""
    import foxglove.layouts as fl

    def delay_plot(key: str, what: str, color: str):
        base = f"{BANDS_TOPIC}.{key}"
        series = [fl.PlotSeries(value=f"{base}.delay_us", label=f"{key} delay (µs)", color=color,
                                timestamp_method="receiveTime"),
                  fl.PlotSeries(value=f"{base}.low_us", label="- 1 std error", color=color, line_style="dashed",
                                line_size=1, timestamp_method="receiveTime"),
                  fl.PlotSeries(value=f"{base}.high_us", label="+ 1 std error", color=color, line_style="dashed",
                                line_size=1, timestamp_method="receiveTime")]
        return fl.SplitItem(proportion=1, content=fl.PlotPanel(
            title=f"{key} delay: {what} (µs, ±1 std error)",
            config=fl.PlotConfig(paths=series, show_legend=True, legend_display="top", y_axis_label="µs",
                                 is_synced=True, x_axis_val="timestamp")))

    loop = fl.PlotPanel(title="current-force loop (/plot/samples, live)", config=fl.PlotConfig(
        paths=[fl.PlotSeries(value="/plot/samples.force_N", label="force (N)", show_line=False,
                             timestamp_method="receiveTime")],
        x_axis_val="custom", x_axis_path=fl.PlotXAxisPath(value="/plot/samples.current_A"),
        x_axis_label="current (A)", y_axis_label="force (N)", show_legend=False))
    envelope = fl.PlotPanel(title="current and force: envelope of each bin (live)", config=fl.PlotConfig(
        paths=[fl.PlotSeries(value=f"/plot/{c}.{k}", label=f"{c} {k}", color=color, timestamp_method="receiveTime",
                             use_right_y_axis=(c == "force_N"))
               for c, color in (("current_A", "#1f77b4"), ("force_N", "#ff7f0e")) for k in ("min", "max")],
        x_axis_val="timestamp", following_view_width=10.0, is_synced=True, show_legend=True,
        legend_display="top", y_axis_label="A (left), N (right)"))
    status = fl.LogPanel(title="status", config=fl.LogConfig(topic_to_render=STATUS_LOG_TOPIC))
    last = fl.RawMessagesPanel(title="last status", config=fl.RawMessagesConfig(topic_path="/status"))
    lay = fl.Layout(
        content=fl.SplitContainer(direction="row", items=[
            fl.SplitItem(proportion=1, content=fl.SplitContainer(
                direction="column", items=[delay_plot(k, what, color) for k, what, color in DELAYS])),
            fl.SplitItem(proportion=1, content=fl.SplitContainer(direction="column", items=[
                fl.SplitItem(proportion=2, content=loop),
                fl.SplitItem(proportion=1, content=envelope),
                fl.SplitItem(proportion=1, content=fl.SplitContainer(direction="row", items=[
                    fl.SplitItem(proportion=2, content=status), fl.SplitItem(proportion=1, content=last)])),
            ])),
        ]),
        user_scripts={"delay_bands": fl.UserScript(name="delay bands", source_code=_BANDS_SCRIPT),
                      "status_log": fl.UserScript(name="status log", source_code=_STATUS_SCRIPT)},
    )
    return json.loads(lay.to_json())


def render() -> str:
    return json.dumps(layout(), indent=2, ensure_ascii=False) + "\n"


def main(argv: list[str] | None = None) -> int:
    return generated_file_main(argv, command=COMMAND, description=__doc__.splitlines()[0], default=LAYOUT_PATH,
                               render=render)


if __name__ == "__main__":
    sys.exit(main())
