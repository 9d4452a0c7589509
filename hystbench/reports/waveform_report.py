"""Report of the measured-waveform diagnosis (:mod:`hystbench.analysis.diagnosis.waveforms`): per row the
measured and predicted B-H loops (before: the rate-independent iron; after: with the named terms) and
H(t), all from the row-held-out models, and the per-row errors against the Paderborn thresholds."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from ..analysis.diagnosis.waveforms import CORR_MIN, REL_L2_MAX, WaveformDiagnosis
from .figures import plt, save_figure

__all__ = ["waveform_row_figure", "waveform_error_figure", "render_waveform_report", "PAGE"]

PAGE = "README.md"


def waveform_row_figure(d: WaveformDiagnosis, row: int, out: Path) -> Path:
    """Loops (left) and H(t) (right, with a zoom on the first 160 samples after the warm-up) of one row."""
    s = d.summary
    w = s["warmup_samples"]
    b, h, h0, h1 = (a[row] for a in (d.b_t, d.h_meas, d.h_before, d.h_after))
    t_us = np.arange(b.size) / d.fs_hz * 1e6
    rb, ra = s["held_out_rows"]["before"], s["held_out_rows"]["after"]
    fig, (lp, ht, zm) = plt.subplots(1, 3, figsize=(15, 4.2), gridspec_kw={"width_ratios": [1, 1.6, 1]})
    after = w + np.arange(b.size - w)
    lp.plot(h[after], 1e3 * b[after], color="k", lw=0.8, label="measured")
    lp.plot(h0[after], 1e3 * b[after], color="C1", lw=0.6, alpha=0.8, label="before (rate-independent)")
    lp.plot(h1[after], 1e3 * b[after], color="C0", lw=0.6, alpha=0.8, label="after (named terms)")
    lp.set_xlabel("H (A/m)")
    lp.set_ylabel("B (mT)")
    lp.set_title(f"row {row}: B-H after the warm-up")
    lp.legend(fontsize=7, loc="upper left")
    for ax, sl in ((ht, slice(None)), (zm, slice(w, w + 160))):
        ax.plot(t_us[sl], h[sl], color="k", lw=0.9, label="measured")
        ax.plot(t_us[sl], h0[sl], color="C1", lw=0.7, label="before")
        ax.plot(t_us[sl], h1[sl], color="C0", lw=0.7, label="after")
        ax.set_xlabel("t (us)")
        ax.set_ylabel("H (A/m)")
    ht.axvspan(0, t_us[w], color="grey", alpha=0.15, lw=0)
    ht.set_title(f"H(t) at {s['temperatures_c'][row]:g} degC; relative L2 {rb['rel_l2'][row]:.3f} -> "
                 f"{ra['rel_l2'][row]:.3f}, corr {rb['corr'][row]:.4f} -> {ra['corr'][row]:.4f}", fontsize=9)
    ht.legend(fontsize=7, loc="upper left")
    zm.set_title("zoom: 10 us after the warm-up", fontsize=9)
    return save_figure(fig, out)


def waveform_error_figure(d: WaveformDiagnosis, out: Path) -> Path:
    """Per-row relative L2 error and correlation, before and after, with the Paderborn thresholds."""
    s = d.summary["held_out_rows"]
    rows = np.arange(len(s["before"]["rel_l2"]))
    fig, (el, co) = plt.subplots(1, 2, figsize=(11, 3.6))
    for ax, key, thr, label in ((el, "rel_l2", REL_L2_MAX, "relative L2 error of H"),
                                (co, "corr", CORR_MIN, "correlation of H")):
        ax.bar(rows - 0.2, s["before"][key], 0.4, color="C1", label="before (rate-independent)")
        ax.bar(rows + 0.2, s["after"][key], 0.4, color="C0", label="after (named terms)")
        ax.axhline(thr, color="r", ls="--", lw=1, label=f"Paderborn test: {'<' if key == 'rel_l2' else '>'} {thr}")
        ax.set_xticks(rows)
        ax.set_xlabel("row (each predicted by the model calibrated on the other fold)")
        ax.set_ylabel(label)
    co.set_ylim(min(0.9, min(s["before"]["corr"]) - 0.01), 1.0)
    el.legend(fontsize=7)
    return save_figure(fig, out)


def render_waveform_report(d: WaveformDiagnosis, folder: str | Path) -> Path:
    """The page and its figures in ``folder``; returns the page."""
    folder = Path(folder)
    s = d.summary
    lines = ["# Diagnosis of measured B(t)/H(t) waveforms", "", f"`{s['path']}`: {s['rows']} rows of "
             f"{s['samples_per_row']} samples at {s['sample_rate_hz'] / 1e6:g} MHz, "
             f"{s['warmup_samples']} of warm-up.", "",
             s["verdict"] + ".", "", f"Split (rows): {s['held_out_rows']['split']}.", "",
             f"Split (time): {s['held_out_time']['split']}.", "", "| row | degC | rel. L2 before | after | corr before "
             "| after |", "|---|---|---|---|---|---|"]
    rb, ra = s["held_out_rows"]["before"], s["held_out_rows"]["after"]
    for i in range(s["rows"]):
        lines.append(f"| {i} | {s['temperatures_c'][i]:g} | {rb['rel_l2'][i]:.3f} | {ra['rel_l2'][i]:.3f} | "
                     f"{rb['corr'][i]:.4f} | {ra['corr'][i]:.4f} |")
    lines += ["", "Parameters (std from the Jacobian, samples taken as independent):", "", "```"]
    lines += _parameter_lines(s["parameters"]["named"] or s["parameters"]["baseline"])
    lines += ["```", "", "What they mean (library's reading; see docs/waveforms.md):", ""]
    lines += [f"- {k} = {v['value']:.4g} {v['unit']}" + (f" ({v['meaning']})" if "meaning" in v else "")
              for k, v in s.get("interpretation", {}).items()]
    lines += ["", f"![errors]({waveform_error_figure(d, folder / 'waveform_errors.png').name})", ""]
    for i in range(s["rows"]):
        png = waveform_row_figure(d, i, folder / f"waveform_row_{i}.png")
        lines += [f"![row {i}]({png.name})", ""]
    page = folder / PAGE
    page.write_text("\n".join(lines), encoding="utf-8")
    return page


def _parameter_lines(params: dict[str, Any]) -> list[str]:
    return [f"{k} = {v['value']:.4g} +- {v['std']:.2g} {v['unit']}" for k, v in params.items()]
