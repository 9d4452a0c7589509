"""Figures of the loss-table diagnosis: held-out energy per cycle against frequency, data vs the
rate-independent baseline (before) and with the named rate-dependent terms (after), and the located
mismatch as a frequency x flux-density heat map of z-scores."""

from __future__ import annotations

from pathlib import Path
from typing import Any, Mapping

import numpy as np

from ..analysis.diagnosis.loss_separation import calibrate_split, diagnose_energy, energy_per_cycle, screened
from ..formats.material_data import read_material_table
from .figures import plt, save_figure

__all__ = ["loss_separation_figure", "loss_shapes_figure"]

_BAND = 0.02  # points within +-5 % (log10 0.02) of a level's flux density are drawn with it


def loss_separation_figure(table_path: str | Path, out: str | Path, split: str = "low_third",
                           levels: int = 4, result: Mapping[str, Any] | None = None) -> Path:
    """One PNG for one material table; returns its path.  ``result``: the table's diagnosis on
    ``split`` where the caller has it (a report draws what it just computed)."""
    table = read_material_table(table_path)
    f, b = table.frequency_hz, table.flux_density_t
    w = energy_per_cycle(table)
    _, (f, b, w, _, _) = screened(f, b, w)  # as the diagnosis leaves them out (named in its verdict)
    train, base, final, _, chosen = calibrate_split(f, b, w, split)
    if result is None:
        result = diagnose_energy(f, b, w, material=table.material, split=split)
    fig, (ax, hm) = plt.subplots(1, 2, figsize=(12, 4.8), gridspec_kw={"width_ratios": [1.25, 1]})
    lb = np.log10(b)
    centres = np.quantile(lb[~train], np.linspace(0.1, 0.9, levels))
    fgrid = np.geomspace(f.min(), f.max(), 100)
    for k, c in enumerate(centres):
        color = f"C{k}"
        near = np.abs(lb - c) <= _BAND
        ax.loglog(f[near & train], w[near & train], "o", mfc="none", color=color, ms=4)
        ax.loglog(f[near & ~train], w[near & ~train], "o", color=color, ms=4, label=f"B = {1e3 * 10**c:.0f} mT")
        bl = np.full_like(fgrid, 10**c)
        ax.loglog(fgrid, np.exp(base.log_w(fgrid, bl)), "--", color=color, lw=1)
        ax.loglog(fgrid, np.exp(final.log_w(fgrid, bl)), "-", color=color, lw=1.3)
    ax.axvline(f[train].max() if split == "low_third" else np.nan, color="grey", lw=0.8, ls=":")
    ax.plot([], [], "k--", lw=1, label="before: rate independent")
    ax.plot([], [], "k-", lw=1.3, label="after: + " + (" + ".join(chosen) or "nothing named"))
    ax.plot([], [], "ko", mfc="none", ms=4, label="calibration points")
    ax.set_xlabel("frequency (Hz)")
    ax.set_ylabel("energy per cycle (J/m$^3$)")
    ax.set_title(f"{table.material} ({table.kind.replace('_', ' ')}), {split}: held-out rms "
                 f"{result['residual_before_log10']:.3f} -> {result['residual_after_log10']:.3f} log10 "
                 f"({_times(result['improvement'])})", fontsize=9)
    ax.legend(fontsize=7, loc="upper left")
    loc = result["located"]
    z = np.array([[np.nan if v is None else v for v in row] for row in loc["z"]])
    lim = max(np.nanmax(np.abs(z)), 1.0)
    im = hm.imshow(z.T, origin="lower", aspect="auto", cmap="RdBu_r", vmin=-lim, vmax=lim)
    top = max(loc["frequencies_Hz"])  # a steel's table is in Hz, a ferrite's in kHz
    scale, unit = (1e6, "MHz") if top >= 1e6 else (1e3, "kHz") if top >= 1e3 else (1.0, "Hz")
    hm.set_xticks(range(len(loc["frequencies_Hz"])), [f"{x / scale:.3g}" for x in loc["frequencies_Hz"]])
    hm.set_yticks(range(len(loc["flux_densities_T"])), [f"{x * 1e3:.4g}" for x in loc["flux_densities_T"]])
    hm.set_xlabel(f"held-out frequency ({unit})")
    hm.set_ylabel("peak flux density (mT)")
    tr = loc["trend"]
    way = "grows" if tr["slope_log_f"] >= 0 else "falls"
    hm.set_title(f"located: z of log10(W meas / W baseline); {way} as f^{tr['slope_log_f']:.2f}", fontsize=9)
    fig.colorbar(im, ax=hm, label="z (noise + model-error floor)")
    return save_figure(fig, Path(out))


#: The duty shapes drawn per group (MagNet's tuples): the calibrated symmetric triangle and the steepest
#: one; the flattest trapezoid (relaxation's) and a middle one.
_SHAPES = {"sine": [(-1.0, -1.0, -1.0, -1.0)], "triangle": [(0.5, 0.0, 0.5, 0.0), (0.1, 0.0, 0.9, 0.0)],
           "trapezoid": [(0.1, 0.4, 0.1, 0.4), (0.3, 0.2, 0.3, 0.2)]}


def loss_shapes_figure(table_paths: list[str | Path], out: str | Path, split: str = "low_third",
                       result: Mapping[str, Any] | None = None) -> Path:
    """One PNG for a material's sine and triangle/trapezoid tables: per shape group, energy per cycle
    against frequency at one flux density (the held-out rows' median), measured (hollow: calibrated on)
    against the baseline (before, dashed) and the selected model (after, solid), for two duty shapes.
    ``result``: the tables' diagnosis on ``split`` where the caller has it."""
    from ..analysis.diagnosis.loss_separation import energy_table, loss_table_groups

    group = loss_table_groups(table_paths)[0]
    f, b, w, duty = energy_table(group)
    _, (f, b, w, duty, _) = screened(f, b, w, duty)  # as the diagnosis leaves them out (named in its verdict)
    if result is None:
        result = diagnose_energy(f, b, w, material=group[0].material, split=split, duty=duty)
    train, base, final, _, chosen = calibrate_split(f, b, w, split, duty)
    level = float(np.median(np.log10(b[~train])))
    fgrid = np.geomspace(f.min(), f.max(), 100)
    fig, axes = plt.subplots(1, 3, figsize=(14, 4.6), sharey=True)
    groups = result.get("shapes", {}).get("groups", {})
    for ax, (name, shapes) in zip(axes, _SHAPES.items()):
        for k, d in enumerate(shapes):
            color = f"C{k}"
            rows = np.all(np.abs(duty - np.array(d)) < 1e-9, axis=1) & (np.abs(np.log10(b) - level) <= _BAND)
            label = "sine" if d[0] == -1 else f"duty {d[0]:g}, {d[1]:g}, {d[2]:g}, {d[3]:g}"
            ax.loglog(f[rows & train], w[rows & train], "o", mfc="none", color=color, ms=4)
            ax.loglog(f[rows & ~train], w[rows & ~train], "o", color=color, ms=4, label=label)
            bl, dl = np.full_like(fgrid, 10**level), np.tile(np.array(d), (fgrid.size, 1))
            ax.loglog(fgrid, np.exp(base.log_w(fgrid, bl)), "--", color=color, lw=1)
            ax.loglog(fgrid, np.exp(final.log_w(fgrid, bl, dl)), "-", color=color, lw=1.4)
        ax.axvline(f[train].max() if split == "low_third" else np.nan, color="grey", lw=0.8, ls=":")
        g = groups.get(name)
        fig_txt = (": none in the table (the models' curves only)" if g is None else
                   f": held-out rms {g['residual_before_log10']:.3f} -> {g['residual_after_log10']:.3f} log10 "
                   f"({_times(g['improvement'])})")
        ax.set_title(f"{name}{fig_txt}", fontsize=9)
        ax.set_xlabel("frequency (Hz)")
        ax.plot([], [], "k--", lw=1, label="before: rate independent")
        ax.plot([], [], "k-", lw=1.4, label="after: + " + (" + ".join(chosen) or "nothing named"))
        ax.plot([], [], "ko", mfc="none", ms=4, label="calibrated on")
        ax.legend(fontsize=7, loc="upper left")
    axes[0].set_ylabel(f"energy per cycle (J/m$^3$) at B = {1e3 * 10**level:.0f} mT")
    fig.suptitle(f"{group[0].material}: sine, triangles and trapezoids, {split} (calibrated on sines and symmetric "
                 f"triangles left of the dotted line); all held out: rms {result['residual_before_log10']:.3f} -> "
                 f"{result['residual_after_log10']:.3f} log10 ({_times(result['improvement'])})", fontsize=10)
    return save_figure(fig, Path(out))


def _times(improvement: float | None) -> str:
    """``12.8x``, or n/a where the model left nothing to improve on (a computed table)."""
    return "n/a" if improvement is None else f"{improvement:.1f}x"
