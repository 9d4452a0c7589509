"""The shipped Foxglove layout (hystbench/config/foxglove_layout.json), built with foxglove-sdk's
layout types so it is a layout Foxglove's own schema describes (docs/foxglove.md says how to open it).

    python -m hystbench.reports.foxglove_layout            # rewrite hystbench/config/foxglove_layout.json
    python -m hystbench.reports.foxglove_layout --check    # exit 1 if the shipped file is out of date
    python -m hystbench.reports.foxglove_layout --bench bench3 --out bench3.json   # bench3 on the fleet view

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

import argparse
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

def _bands_script(prefix: str) -> str:
    return f"""\
// Each estimate's three delays in microseconds with their one-standard-error bounds: the Plot
// panel draws no error bars, so the bounds are plotted as dashed lines. Refused windows (no
// delays) publish nothing.
import {{ Input }} from "./types";

export const inputs = ["{prefix}/estimate"];
export const output = "{BANDS_TOPIC}";

type Band = {{ delay_us: number; low_us: number; high_us: number }};
type Output = {{ hysteresis: Band; instrument: Band; total: Band }};
type Delays = Record<string, number | null | undefined>;

function band(d: Delays, s: Delays, k: string): Band | undefined {{
  const v = d[k], e = s[k] ?? 0;
  if (v === null || v === undefined) return undefined;
  return {{ delay_us: v * 1e6, low_us: (v - e) * 1e6, high_us: (v + e) * 1e6 }};
}}

export default function script(event: Input<"{prefix}/estimate">): Output | undefined {{
  const m = event.message as unknown as {{ delays_s?: Delays; delays_std_s?: Delays }};
  const d = m.delays_s ?? {{}}, s = m.delays_std_s ?? {{}};
  const h = band(d, s, "hysteresis"), i = band(d, s, "instrument"), t = band(d, s, "total");
  if (!h || !i || !t) return undefined;
  return {{ hysteresis: h, instrument: i, total: t }};
}}
"""

def _status_script(prefix: str) -> str:
    return f"""\
// The daemon's status messages (hystbench.Status) as foxglove.Log, the one schema the Log panel
// shows: level info/warning/error, the event as the name, the message and its other fields.
import {{ Input }} from "./types";
import {{ Log }} from "@foxglove/schemas";

export const inputs = ["{prefix}/status"];
export const output = "{STATUS_LOG_TOPIC}";

const LEVELS: Record<string, number> = {{ info: 2, warning: 3, error: 4 }};

export default function script(event: Input<"{prefix}/status">): Log {{
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


def layout(bench: str | None = None) -> dict[str, Any]:
    """The layout as Foxglove's layout JSON (a dict): of a daemon's own view (and its logs), or with
    ``bench`` of that bench on the router's fleet view (its topics under ``/<bench>``; that view has
    no ``/plot`` channels, so no loop or envelope panels)."""
    import foxglove.layouts as fl

    prefix = f"/{bench}" if bench else ""

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
    last = fl.RawMessagesPanel(title="last status", config=fl.RawMessagesConfig(topic_path=f"{prefix}/status"))
    logs = fl.SplitContainer(direction="row", items=[
        fl.SplitItem(proportion=2, content=status), fl.SplitItem(proportion=1, content=last)])
    right = [fl.SplitItem(proportion=2, content=loop), fl.SplitItem(proportion=1, content=envelope),
             fl.SplitItem(proportion=1, content=logs)] if not bench else [fl.SplitItem(proportion=1, content=logs)]
    lay = fl.Layout(
        content=fl.SplitContainer(direction="row", items=[
            fl.SplitItem(proportion=1, content=fl.SplitContainer(
                direction="column", items=[delay_plot(k, what, color) for k, what, color in DELAYS])),
            fl.SplitItem(proportion=1, content=fl.SplitContainer(direction="column", items=right)),
        ]),
        user_scripts={"delay_bands": fl.UserScript(name="delay bands", source_code=_bands_script(prefix)),
                      "status_log": fl.UserScript(name="status log", source_code=_status_script(prefix))},
    )
    return json.loads(lay.to_json())


def render(bench: str | None = None) -> str:
    return json.dumps(layout(bench), indent=2, ensure_ascii=False) + "\n"


def main(argv: list[str] | None = None) -> int:
    """The shipped layout (generated_file_main), or with ``--bench NAME --out FILE`` one bench's
    layout for the fleet view (``hystbench router --foxglove``)."""
    argv = list(sys.argv[1:] if argv is None else argv)
    if "--bench" not in argv:
        return generated_file_main(argv, command=COMMAND, description=__doc__.splitlines()[0] + (
            " (--bench NAME --out FILE: one bench's layout for the router's fleet view)"), default=LAYOUT_PATH,
                                   render=render)
    from ..acquisition.zenoh_bus import key
    from ..errors import BenchError
    from ..formats.outputs import output_file

    ap = argparse.ArgumentParser(prog=f"{COMMAND} --bench", description="one bench's layout for the fleet view")
    ap.add_argument("--bench", required=True, help="the bench's name, as its daemon's [daemon] bench")
    ap.add_argument("--out", type=Path, required=True, help="the layout file to write (JSON)")
    ap.add_argument("--overwrite", action="store_true")
    a = ap.parse_args(argv)
    try:
        key(a.bench)  # a name zenoh can route, or one line naming it
        with output_file(a.out, overwrite=a.overwrite) as tmp:
            tmp.write_text(render(a.bench), encoding="utf-8")
    except BenchError as err:
        print(f"{COMMAND}: error: {err}", file=sys.stderr)
        return 2
    print(f"wrote {a.out}: the layout of bench {a.bench} on the fleet view")
    return 0


if __name__ == "__main__":
    sys.exit(main())
