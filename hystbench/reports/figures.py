"""PNG figures a reader of the paper recognises.  matplotlib with the Agg backend, no display."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any, Sequence

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from ..config import load_rig, rig_names  # noqa: E402
from ..errors import ConfigError  # noqa: E402
from ..physics import presets  # noqa: E402

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from numpy.typing import ArrayLike
    from matplotlib.figure import Figure

__all__ = ["plt", "save_figure", "force_map_figure", "loops_figure", "draw_nested_loops", "zoom_on_the_middle",
           "check_ecore"]


def save_figure(fig: Figure, path: Path, dpi: int = 110) -> Path:
    """Lay out, write as PNG (making the folder) and free the figure; returns the path."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.tight_layout()
    fig.savefig(path, dpi=dpi)
    plt.close(fig)
    return path


def check_ecore(rig: str) -> dict:
    """The preset ``rig`` if it is an E-core; the force map is the E-core's magnetic circuit (Eq. 1),
    which a voice coil or a toroid does not have."""
    preset = load_rig(rig)
    if preset.get("actuator") != "ecore":
        ecores = [n for n in rig_names() if load_rig(n).get("actuator") == "ecore"]
        raise ConfigError(f"--rig {rig}: a {preset.get('actuator')}; the force map (paper Fig. 3) is drawn for "
                          f"E-cores only, the presets {', '.join(ecores)} (or an E-core TOML)")
    return preset


def force_map_figure(rig: str, out: Path) -> Path:
    """Static force F(i, z) of an E-core preset over current and airgap (paper Fig. 3)."""
    preset = check_ecore(rig)
    mec = presets.ecore_mec(preset, linear_iron=True)
    current = np.linspace(-2.0, 2.0, 41)
    airgap = np.linspace(0.1e-3, 1.5e-3, 40)
    force = mec.force_map(current, airgap)
    i, z = np.meshgrid(current, airgap * 1e3, indexing="ij")
    fig = plt.figure(figsize=(7, 5))
    ax = fig.add_subplot(projection="3d")
    surface = ax.plot_surface(i, z, force, cmap="viridis", edgecolor="none")
    fig.colorbar(surface, ax=ax, shrink=0.6, pad=0.12, label="$F_z$ (N)")
    ax.set_xticks([-2, -1, 0, 1, 2])
    ax.view_init(elev=25, azim=-130)
    ax.set_xlabel("Current (A)")
    ax.set_ylabel("Airgap (mm)")
    ax.set_zlabel("$F_z$ (N)")
    z0 = mec.geometry.airgap_m * 1e3
    ax.set_title(f"{rig}: static force (MEC, Eq. 1); nominal airgap {z0:g} mm")
    return save_figure(fig, out, dpi=120)


def loops_figure(curves: list[tuple[str, np.ndarray, np.ndarray]], xlabel: str, ylabel: str,
                 title: str, out: Path) -> Path:
    """One panel of loops (label, x, y), e.g. current vs force per frequency (paper Figs. 10, 14)."""
    fig, ax = plt.subplots(figsize=(6.4, 4.6))
    draw_nested_loops(ax, curves)
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="upper left")
    zoom_on_the_middle(ax, curves)
    return save_figure(fig, out, dpi=120)


def zoom_on_the_middle(ax: Axes, curves: Sequence[tuple[str, ArrayLike, ArrayLike]]) -> None:
    """An inset magnifying the loops' middle (a tenth of the x range), where their openings differ
    most visibly; skipped when the loops are too few or too flat to need it."""
    xs = np.concatenate([np.asarray(x, float) for _, x, _ in curves])
    lo, hi = float(xs.min()), float(xs.max())
    if len(curves) < 2 or not hi > lo:
        return
    mid, half = 0.5 * (lo + hi), 0.05 * (hi - lo)
    ys = np.concatenate([np.asarray(y, float)[np.abs(np.asarray(x, float) - mid) <= half] for _, x, y in curves])
    if ys.size < 2 or not np.ptp(ys) > 0:
        return
    inset = ax.inset_axes([0.58, 0.07, 0.39, 0.38])
    draw_nested_loops(inset, curves, width=0.5)
    pad = 0.08 * float(np.ptp(ys))
    inset.set_xlim(mid - half, mid + half)
    inset.set_ylim(float(ys.min()) - pad, float(ys.max()) + pad)
    inset.tick_params(labelsize=6)
    inset.set_title("middle, magnified", fontsize=7)
    ax.indicate_inset_zoom(inset, edgecolor="0.4")


def draw_nested_loops(ax: Axes, curves: Sequence[tuple[str, ArrayLike, ArrayLike]], *, width: float = 1.0,
                      **kw: Any) -> None:
    """Loops that lie almost on one another (one per frequency, each barely wider than the one
    before) all visible: the first is drawn last and thinnest, on top, each earlier-listed one
    thinner than the next, so every loop shows as its own coloured band; the legend keeps the
    given order.  ``width``: the first loop's line width, pt (the others scale with it)."""
    n = len(curves)
    colours = [plt.get_cmap("tab10")(k % 10) for k in range(n)]  # neighbours distinct, not a ramp
    widths = width * np.linspace(1.0, 1.0 + 0.9 * (n - 1), n)
    for k, (label, x, y) in enumerate(curves):
        ax.plot(x, y, label=label, lw=float(widths[k]), color=colours[k], zorder=2 + n - k, solid_capstyle="round",
                **kw)
