"""Figures of the loss-table diagnosis: held-out energy per cycle against frequency, data vs the
rate-independent baseline (before) and with the named rate-dependent terms (after), and the located
mismatch as a frequency x flux-density heat map of z-scores."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..analysis.diagnosis.loss_separation import calibrate_split, diagnose_energy, energy_per_cycle
from ..formats.material_data import read_material_table
from .figures import plt, save_figure

__all__ = ["loss_separation_figure"]

_BAND = 0.02  # points within +-5 % (log10 0.02) of a level's flux density are drawn with it


def loss_separation_figure(table_path: str | Path, out: str | Path, split: str = "low_third",
                           levels: int = 4) -> Path:
    """One PNG for one material table; returns its path."""
    table = read_material_table(table_path)
    f, b = table.frequency_hz, table.flux_density_t
    w = energy_per_cycle(table)
    train, base, final, _, chosen = calibrate_split(f, b, w, split)
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
                 f"({result['improvement']:.1f}x)", fontsize=9)
    ax.legend(fontsize=7, loc="upper left")
    loc = result["located"]
    z = np.array([[np.nan if v is None else v for v in row] for row in loc["z"]])
    lim = max(np.nanmax(np.abs(z)), 1.0)
    im = hm.imshow(z.T, origin="lower", aspect="auto", cmap="RdBu_r", vmin=-lim, vmax=lim)
    hm.set_xticks(range(len(loc["frequencies_Hz"])), [f"{x / 1e3:.0f}" for x in loc["frequencies_Hz"]])
    hm.set_yticks(range(len(loc["flux_densities_T"])), [f"{x * 1e3:.0f}" for x in loc["flux_densities_T"]])
    hm.set_xlabel("held-out frequency (kHz)")
    hm.set_ylabel("peak flux density (mT)")
    tr = loc["trend"]
    hm.set_title(f"located: z of log10(W meas / W baseline); grows as f^{tr['slope_log_f']:.2f}", fontsize=9)
    fig.colorbar(im, ax=hm, label="z (noise + model-error floor)")
    return save_figure(fig, Path(out))
