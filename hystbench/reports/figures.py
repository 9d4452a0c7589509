"""PNG figures a reader of the paper recognises.  matplotlib with the Agg backend, no display."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from ..config import load_rig, rig_names  # noqa: E402
from ..errors import ConfigError  # noqa: E402
from ..physics import presets  # noqa: E402

if TYPE_CHECKING:
    from matplotlib.figure import Figure

__all__ = ["plt", "save_figure", "force_map_figure", "loops_figure", "check_ecore"]


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
    ax.plot_surface(i, z, force, cmap="viridis", edgecolor="none")
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
    for label, x, y in curves:
        ax.plot(x, y, label=label, lw=1.2)
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    return save_figure(fig, out, dpi=120)
