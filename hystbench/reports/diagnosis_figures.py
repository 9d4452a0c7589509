"""Figures of the diagnosis: where the simulation and the recordings differ, at a glance."""

from __future__ import annotations

import textwrap
from pathlib import Path

import numpy as np
from matplotlib.colors import SymLogNorm

from ..analysis.diagnosis.locate import Located
from .figures import plt, save_figure

__all__ = ["heat_map", "CAPTION", "NO_CELL"]

#: |z| below this is chance (a few units); the colour scale is linear there, logarithmic above,
#: so z = 5 and z = 500 are both told apart.
LINEAR_Z = 3.0


#: what a grey cell is
NO_CELL = "Grey: no such cell (that recording lacks the channel or the harmonic)"
#: the caption under the map: what its rows and colours mean
CAPTION = ("Rows: view (channel pair) and k, the harmonic (k x the excitation frequency; k = 0 the mean; "
           "'line' rows: mains lines). Colour: z, how far the residual lies beyond its noise "
           "(red: the model leaves something out; blue: fits better than its noise).")


def heat_map(located: Located, path: Path) -> Path:
    """The residual's z per (view, harmonic) row and recording column (sweep order), as a PNG:
    red where the model leaves something out, blue where it fits better than its noise, grey where
    a recording has no such cell."""
    rows, cols, z = located.grid()
    path = Path(path)
    if not rows or not cols:
        fig, ax = plt.subplots(figsize=(5, 2))
        ax.axis("off")
        ax.text(0.5, 0.5, "nothing to locate: no residual entries", ha="center", va="center")
        return save_figure(fig, path)
    top = float(np.nanmax(np.abs(z))) if np.isfinite(z).any() else LINEAR_Z
    top = max(top, 2 * LINEAR_Z)
    cmap = plt.get_cmap("RdBu_r").with_extremes(bad="0.85")
    width = min(22.0, max(6.5, 3.5 + 0.28 * len(cols)))  # at least the caption's and colour bar's room
    height = min(30.0, 2.2 + 0.22 * len(rows))
    fig, ax = plt.subplots(figsize=(width, height + 0.8))  # + the caption's lines
    image = ax.imshow(np.ma.masked_invalid(z), aspect="auto", interpolation="nearest", cmap=cmap,
                      norm=SymLogNorm(linthresh=LINEAR_Z, vmin=-top, vmax=top, base=10))
    ax.set_yticks(range(len(rows)), rows, fontsize=8)
    ax.set_xticks(range(len(cols)), cols, rotation=90, fontsize=8)
    views = [r.split(",")[0] for r in rows]  # a line between views
    for i in range(1, len(rows)):
        if views[i] != views[i - 1]:
            ax.axhline(i - 0.5, color="k", lw=0.8)
    rigs = [c.split(" ")[0] for c in cols]  # a line between rigs
    for j in range(1, len(cols)):
        if rigs[j] != rigs[j - 1]:
            ax.axvline(j - 0.5, color="k", lw=0.8)
    bar = fig.colorbar(image, ax=ax, fraction=0.04, pad=0.02)
    ticks = [0.0] + [s * v for v in (LINEAR_Z, 10, 30, 100, 300, 1000, 3000, 10000) if v <= top for s in (1, -1)]
    bar.set_ticks(sorted(ticks), labels=[f"{v:g}" for v in sorted(ticks)])
    bar.set_label("z (chi-square standard score)")
    strongest = located.top(1)
    title = "Where the simulation and the recordings differ"
    if strongest:
        title += f"\nstrongest: {strongest[0]['text']}"
    if located.floor_note:
        title += f"\n{located.floor_note}"
    ax.set_title(title, fontsize=9)
    ax.set_ylabel("view, k = harmonic")
    # the caption under the map (in the x label, so the layout makes room for it): what k, the
    # colours and a grey cell mean
    caption = CAPTION + (" " + NO_CELL + "." if np.isnan(z).any() else "")
    chars = int(14 * width)  # a line of the caption, in characters of its 8-pt font
    ax.set_xlabel("recording (sweep order)\n\n" + textwrap.fill(caption, chars), fontsize=8, loc="left")
    return save_figure(fig, path)
