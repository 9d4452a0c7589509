"""``hystbench fit-material``: the hysteresis model against the real measured B-H loops.

Loads (or, with ``refit``, fits again and writes beside the figures) the material files, draws measured and modelled
loops with the B error along each, and reports the error table and M330-50A's phase lag at the
E-core's operating points, so anyone can see how far the simulated iron is from real iron.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from ..config import load_material
from ..physics import material_fit as mf
from ..physics.hysteresis import PreisachHysteresis
from ..physics.hysteresis_kernel import field_along
from .figures import plt, save_figure as _save

__all__ = ["run_material_fit", "OPERATING_POINTS", "FIT_SETTINGS"]

#: (B amplitude, B bias) in T of the E-core's iron: without and with the pre-biasing magnet
OPERATING_POINTS = ((0.13, 0.0), (0.13, 0.81))
#: material -> fit settings (field range of the model's relays, shapes of the switching-field density)
FIT_SETTINGS = {
    "M330-50A": dict(h_max_a_per_m=5.0e4, kinds=("gauss", "lorentz", "lorentz")),
    "M130-27S": dict(h_max_a_per_m=1.0e4, kinds=("gauss", "lorentz", "lorentz")),
}
_HEADER = """{name}: factorised Preisach model of the static (rate-independent) B-H loops.
Fitted to real measured loops: shared/data/real/{data}
({source}).
Residuals: B error at the measured H in units of each loop's Bm, and the relative loop area.
Written by hystbench.reports.material_report.run_material_fit(out_dir, refit=True);
regenerate with:  hystbench fit-material --refit --out DIR  (then copy DIR/*.toml into
hystbench/config/materials/ to ship it)"""
_SOURCES = {"M330-50A": "Epstein frame, Modelica Standard Library tables, BSD-3-Clause",
            "M130-27S": "R. Szewczyk, JAmodel repository, MIT; three loops, one parameter set"}


def _refit(name: str, materials_dir: Path) -> Path:
    loops = mf.load_loops(name)
    params = mf.fit_material(loops, **FIT_SETTINGS[name])
    model = PreisachHysteresis(params)
    errors = {lp.label: mf.loop_error(model, lp) for lp in loops}
    header = _HEADER.format(name=name, data=mf.MATERIAL_DATA[name][0], source=_SOURCES[name])
    materials_dir.mkdir(parents=True, exist_ok=True)
    path = materials_dir / f"{name}.toml"
    path.write_text(mf.material_toml(name, params, header, errors))
    return path


def _dense_loop(model: PreisachHysteresis, h_max: float, n: int = 1500) -> tuple[np.ndarray, np.ndarray]:
    """Model loop on a fine H grid (dense near H = 0), for smooth lines."""
    x = np.arcsinh(h_max / 5.0)
    down = 5.0 * np.sinh(np.linspace(x, -x, n))
    h = np.concatenate([[h_max], down, down[::-1][1:]])
    b, _ = model.flux_density(h, model.initial_state())
    return h[1:], b[1:]


def _error_panel(ax, model, loops, colors) -> None:
    for lp, c in zip(loops, colors):
        e = (mf.model_loop(model, lp) - lp.b_t) * 1e3
        k = lp.turn + 1
        ax.plot(lp.h_a_per_m[:k], e[:k], "-", color=c, lw=1, label=f"{lp.label}: descending")
        ax.plot(lp.h_a_per_m[k - 1:], e[k - 1:], "--", color=c, lw=1, label=f"{lp.label}: ascending")
    ax.axhline(0, color="0.6", lw=0.6)
    ax.set_ylabel("B error, model − measured (mT)")
    ax.legend(fontsize=7)
    ax.grid(alpha=0.3)


def _figure_m330(model, loops, out: Path) -> Path:
    lp = loops[0]
    h, b = _dense_loop(model, lp.h_max)
    fig, axes = plt.subplots(1, 3, figsize=(16, 5))
    for ax, lim in zip(axes[:2], (None, 300.0)):
        ax.plot(lp.h_a_per_m, lp.b_t, "o", ms=3, color="k", label="measured (Epstein)")
        ax.plot(h, b, "-", color="C3", lw=1.2, label="Preisach model")
        ax.set_xlabel("H (A/m)")
        ax.set_ylabel("B (T)")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8, loc="lower right")
    axes[0].set_xscale("symlog", linthresh=100.0)
    axes[0].set_title("M330-50A major loop to ±50 kA/m (symlog H)")
    axes[1].set_xlim(-lim, lim)
    axes[1].set_title("the same, |H| ≤ 300 A/m")
    _error_panel(axes[2], model, loops, ["C0"])
    axes[2].set_xscale("symlog", linthresh=100.0)
    axes[2].set_xlabel("H (A/m, symlog)")
    axes[2].set_title("B error at the measured H")
    return _save(fig, out / "M330-50A_loops.png")


def _figure_m130(model, loops, out: Path) -> Path:
    fig, axes = plt.subplots(1, 2, figsize=(13, 5))
    colors = ["C0", "C1", "C2"]
    for lp, c in zip(loops, colors):
        h, b = _dense_loop(model, lp.h_max, 600)
        axes[0].plot(lp.h_a_per_m, lp.b_t, "o", ms=2.5, color=c, alpha=0.6, label=f"measured, {lp.label}")
        axes[0].plot(h, b, "-", color=c, lw=1.2)
    axes[0].plot([], [], "-", color="k", label="Preisach model, one parameter set")
    axes[0].set_xlabel("H (A/m)")
    axes[0].set_ylabel("B (T)")
    axes[0].set_title("M130-27S (grain-oriented), three amplitudes")
    axes[0].legend(fontsize=8, loc="lower right")
    axes[0].grid(alpha=0.3)
    _error_panel(axes[1], model, loops, colors)
    axes[1].set_xlabel("H (A/m)")
    axes[1].set_title("B error at the measured H")
    return _save(fig, out / "M130-27S_loops.png")


def _figure_operating(model, lags: dict[str, float], out: Path) -> Path:
    fig, ax = plt.subplots(figsize=(7, 5.5))
    hm, bm = _dense_loop(model, 2000.0)
    ax.plot(hm, bm, "-", color="0.75", lw=1, label="loop to ±2 kA/m")
    ph = 2 * np.pi * np.arange(2000) / 1000
    for (amp, bias), (label, lag), c in zip(OPERATING_POINTS, lags.items(), ("C0", "C3")):
        b = bias + amp * np.sin(ph)
        state = field_along(model, np.array([bias]), model.initial_state())[1]
        h, _ = field_along(model, b, state)
        ax.plot(h[1000:], b[1000:], "-", color=c, lw=1.5, label=f"{label}: B lags H by {lag:.1f}°")
    ax.set_xlim(-150, 250)
    ax.set_ylim(-1.0, 1.6)
    ax.set_xlabel("H (A/m)")
    ax.set_ylabel("B (T)")
    ax.set_title("M330-50A: B-driven minor loops at the E-core's operating points")
    ax.legend(fontsize=8, loc="lower right")
    ax.grid(alpha=0.3)
    return _save(fig, out / "M330-50A_operating_points.png")



def run_material_fit(out_dir: Path, *, refit: bool = False, materials_dir: Path | None = None) -> dict[str, Any]:
    """Figures and error table for M330-50A and M130-27S; ``refit`` fits again and writes the
    material files to ``materials_dir`` (default ``out_dir``), never over the shipped ones: the
    package's ``config/materials`` changes only when someone copies a reviewed fit there."""
    out_dir = Path(out_dir)
    mdir = Path(materials_dir) if materials_dir else out_dir
    result: dict[str, Any] = {"figures": {}, "errors": {}, "baseline_errors": {}, "material_files": {}}
    models = {}
    for name in FIT_SETTINGS:
        path = _refit(name, mdir) if refit else None
        material = load_material(path if path else name)
        result["material_files"][name] = material["_source"]
        models[name] = model = PreisachHysteresis.from_config(material)
        loops = mf.load_loops(name)
        for lp in loops:
            result["errors"][lp.label] = mf.loop_error(model, lp)
            result["baseline_errors"][lp.label] = mf.baseline_error(lp)
        draw = _figure_m330 if name == "M330-50A" else _figure_m130
        result["figures"][f"{name}_loops"] = str(draw(model, loops, out_dir))
    lags = {f"B = {b:g} T ± {a:g} T": mf.operating_point_lag_deg(models["M330-50A"], a, b) for a, b in OPERATING_POINTS}
    result["phase_lag_deg"] = lags
    result["figures"]["M330-50A_operating_points"] = str(_figure_operating(models["M330-50A"], lags, out_dir))
    return result
