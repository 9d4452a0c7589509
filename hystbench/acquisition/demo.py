"""``make demo``: the main job on the embedded simulated rig.

Simulates the paper's two E-core sweeps (without magnet at 1.27 A-pp, with magnet at 1.4 A-pp),
writes them as recordings, reads them back, measures the three delays of each, and leaves a summary
table, a JSON summary and figures (force map, current-force loops, delays vs frequency).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from rich.console import Console
from rich.progress import Progress
from rich.table import Table

from ..config import load_rig
from ..physics import presets
from ..sim_backend.rig import SimulatedRig
from .figures import force_map_figure, loops_figure
from .method import measure_delays
from .operating_points import PAPER_FORCE_RANGES_N
from .recording import Recording, read_sweep, write_sweep

__all__ = ["run_demo", "SWEEPS"]

#: (rig, A-pp, frequencies): the paper's measurement series (Secs. V and VI).
SWEEPS = (("ecore", 1.27, (40.0, 80.0, 160.0, 320.0)),
          ("ecore_pm", 1.4, (40.0, 80.0, 160.0, 320.0, 480.0)))
DURATION_S = 0.5


def _period_average(rec: Recording, name: str) -> tuple[np.ndarray, np.ndarray]:
    """(current, channel) averaged over whole periods at the nominal frequency (for loop plots)."""
    per = rec.fs_hz / rec.frequency_hz
    n_per = int(np.floor(rec.n / per))
    m = int(round(per))
    idx = (np.arange(n_per)[:, None] * per + np.arange(m)[None, :]).round().astype(int)
    i, x = rec.channels["current_A"][idx].mean(axis=0), rec.channels[name][idx].mean(axis=0)
    return np.append(i, i[0]), np.append(x, x[0])  # closed loop


def run_demo(out: Path) -> int:
    console = Console()
    out.mkdir(parents=True, exist_ok=True)
    console.rule("hystbench demo: the simulated rig, the paper's E-core sweeps")
    summary: dict = {"sweeps": {}}
    with Progress(console=console, transient=True) as progress:
        task = progress.add_task("simulating", total=sum(len(f) for _, _, f in SWEEPS))
        for rig_name, ipp, freqs in SWEEPS:
            recs = []
            for n, f in enumerate(freqs):
                rig = SimulatedRig(rig_name, seed=n, frequency_hz=f, current_pp_a=ipp)
                block = rig.record(DURATION_S)
                recs.append(Recording(None, rig.fs_hz, dict(block.channels), rig.metadata()))
                progress.advance(task)
            write_sweep(recs, out / "sweeps" / rig_name, overwrite=True)

    table = Table(title=f"delays measured from the recordings ({DURATION_S:g} s each, 100 kS/s)")
    for col in ("rig", "f (Hz)", "force range (N)", "paper range (N)", "flux behind current (deg)",
                "force behind flux (deg)", "instrument model (deg)", "force behind current (deg)"):
        table.add_column(col, justify="right")
    figures = [force_map_figure("ecore_pm", out / "force_map.png")]
    for rig_name, ipp, _ in SWEEPS:
        recs = read_sweep(out / "sweeps" / rig_name)
        instrument = presets.instrument(load_rig(rig_name))
        lo, hi, _ = PAPER_FORCE_RANGES_N[rig_name]
        rows, curves = [], []
        for rec in recs:
            d = measure_delays(rec)
            i_avg, f_avg = _period_average(rec, "force_N")
            k = d.harmonic
            model_deg = -float(instrument.phase_deg(k * d.frequency_hz)) / k
            row = {"frequency_Hz": rec.frequency_hz, "force_min_N": float(f_avg.min()),
                   "force_max_N": float(f_avg.max()), "instrument_model_deg": model_deg, **d.as_dict()}
            rows.append(row)
            curves.append((f"{rec.frequency_hz:g} Hz", i_avg, f_avg))
            table.add_row(rig_name, f"{rec.frequency_hz:g}", f"{row['force_min_N']:.2f} - {row['force_max_N']:.2f}",
                          f"{lo:g} - {hi:g}", f"{d.phase_deg('hysteresis'):.3f}", f"{d.phase_deg('instrument'):.3f}",
                          f"{model_deg:.3f}", f"{d.phase_deg('total'):.3f}")
        summary["sweeps"][rig_name] = rows
        figures.append(loops_figure(curves, "Current (A)", "$F_z$ (N)",
                                    f"{rig_name}, {ipp:g} A-pp: measured current vs force (period-averaged)",
                                    out / f"{rig_name}_current_force.png"))
    console.print(table)
    summary["figures"] = [str(p) for p in figures]
    (out / "summary.json").write_text(json.dumps(summary, indent=2))
    console.print(f"recordings in {out / 'sweeps'}, figures and summary.json in {out}")
    return 0
