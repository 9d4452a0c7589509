"""The force models' bench family on the independent bench (issue 29): iron whose loops are ellipses
(the paper's Sec. II B picture) and this bench's Bouc-Wen iron with pointed loops, each with and
without the magnet.  For each bench, what its user records: the identification sweep, recordings
the fit never sees, and the ferrite voice coil's sweep on the same load cell for the instrument.

Like the rest of the package, it imports nothing from ``hystbench``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .bench import BASELINE, VARIANTS, write_bench_day

__all__ = ["FAMILY", "MAIN_IPP", "fit_plan", "judge_plan", "voice_coil_plan", "write_family_bench"]

#: The irons, as this bench's effect tables on top of BASELINE.
IRONS: dict[str, dict] = {"elliptic": {"static_hysteresis": dict(VARIANTS["static_hysteresis"])},
                          "bouc_wen": {"static_hysteresis": True}}
#: The benches: ``RIG~IRON``.
FAMILY: tuple[str, ...] = tuple(f"{rig}~{iron}" for iron in IRONS for rig in ("ecore_pm", "ecore"))
#: The paper's amplitude per rig (A-pp).
MAIN_IPP = {"ecore": 1.27, "ecore_pm": 1.4}


def fit_plan(rig: str) -> list[tuple[str, float, float]]:
    """The identification sweep: 40, 160, 480 Hz x 0.3-1.5 A-pp (hystbench's FIT_GRID)."""
    return [(rig, f, i) for f in (40.0, 160.0, 480.0) for i in (0.3, 0.7, 1.1, 1.5)]


def judge_plan(rig: str) -> list[tuple[str, float, float]]:
    """What the fit never sees: 40-480 Hz at the paper's amplitude and at 0.9 A-pp."""
    return [(rig, f, i) for f in (40.0, 80.0, 160.0, 320.0, 480.0) for i in (MAIN_IPP[rig], 0.9)]


def voice_coil_plan() -> list[tuple[str, float, float]]:
    """The ferrite voice coil's stepped sine, through the load cell's resonance (paper Sec. IV)."""
    return [("voicecoil_ferrite", float(f), 1.0) for f in np.round(np.geomspace(40.0, 30000.0, 14), 1)]


def write_family_bench(name: str, folder: str | Path, seed: int = 2900) -> dict[str, Path]:
    """Write bench ``name``'s three sweeps under ``folder`` (``fit/``, ``judge/``, ``voicecoil/``);
    returns them by that name."""
    rig, iron = name.split("~")
    if name not in FAMILY:
        raise ValueError(f"unknown bench {name!r}; known: {', '.join(FAMILY)}")
    effects = {**BASELINE, **IRONS[iron]}
    folder = Path(folder)
    out = {"fit": folder / "fit", "judge": folder / "judge", "voicecoil": folder / "voicecoil"}
    write_bench_day(out["fit"], effects=effects, seed=seed, periods=16, plan=fit_plan(rig))
    write_bench_day(out["judge"], effects=effects, seed=seed + 1, periods=80, plan=judge_plan(rig))
    write_bench_day(out["voicecoil"], effects=effects, seed=seed + 2, periods=48, fs_hz=400e3, plan=voice_coil_plan())
    return out
