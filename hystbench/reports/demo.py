"""``make demo``: the main job on the embedded simulated rig.

Acquires the paper's two E-core sweeps (without magnet at 1.27 A-pp, with magnet at 1.4 A-pp)
through the real drivers from the emulated instruments (SCPI generator, Modbus amplifier, ASCII
charge amplifier, CAN FD flux integrator, all fed by one simulated rig), writes them as
recordings, reads them back, measures the three delays of each, and leaves a summary table, a
JSON summary and figures (force map, current-force loops).
"""

from __future__ import annotations

import dataclasses
import json
import shutil
from pathlib import Path

import numpy as np
from rich.table import Table

from ..config import load_rig
from ..physics import presets
from ..drivers.bench import Bench
from ..drivers.protocols.bench_config import load_bench_config
from ..errors import BenchError, RecordingError
from ..sim_backend.emulators.bench import EmulatedBench
from .console import console as make_console, progress as make_progress
from .figures import force_map_figure, loops_figure
from ..analysis.method import measure_delays
from ..analysis.periodic import synchronous_average
from ..formats.recording import Recording, read_sweep, write_sweep

__all__ = ["run_demo", "demo_sweeps", "SWEEPS", "sample_source"]

#: (rig, A-pp, frequencies): the paper's measurement series (Secs. V and VI).
SWEEPS = (("ecore", 1.27, (40.0, 80.0, 160.0, 320.0)),
          ("ecore_pm", 1.4, (40.0, 80.0, 160.0, 320.0, 480.0)))
DURATION_S = 0.5
SETTLE_S = 0.1  # after each step: the chain rings ~30 ms (analysis.settling); the rest covers samples in flight


def _loop(rec: Recording, frequency_hz: float, name: str) -> tuple[np.ndarray, np.ndarray]:
    """(current, channel) averaged over whole periods at the true frequency, closed (for loop plots)."""
    avg = synchronous_average(rec, frequency_hz, 1000, ("current_A", name))
    i, x = avg.channels["current_A"], avg.channels[name]
    return np.append(i, i[0]), np.append(x, x[0])


def sample_source(bench_file: str | Path | None = None) -> str:
    """Where the demo's samples come from, for its headers and the recordings' metadata."""
    dig = load_bench_config(bench_file).digitiser
    if dig is None:
        return "the emulated instruments' own streams"
    return f"the {'emulated ' if dig.is_sim else ''}SCPI digitiser ({dig.dialect} dialect, pyvisa-py)" \
        if dig.kind == "visa" else "the NI-DAQmx card"


def _sweep_through_drivers(rig_name: str, ipp: float, freqs, advance,
                           bench_file: str | Path | None = None) -> list[Recording]:
    """One sweep as the bench engineer takes it: the shipped bench file (or ``bench_file``, e.g.
    the digitiser's) with every instrument emulated, the generator stepped through the
    frequencies, each point acquired by the drivers."""
    config = load_bench_config(bench_file)
    config = dataclasses.replace(config, sim={**config.sim, "rig": rig_name})
    recs = []
    with EmulatedBench(config) as emu, Bench(config.resolved(emu.addresses)) as bench:
        vpp = ipp / bench.budget.gain_a_per_v
        for n, f in enumerate(freqs):
            bench.generator.set_sine(f, vpp, 0.0)
            if n == 0:
                bench.start_output()
            bench.commanded()
            bench.acquire(SETTLE_S, since_command=True)  # none of the last frequency: the settling starts at the change
            runs = bench.acquire(DURATION_S)
            if len(runs) != 1:  # a gap: the demo would rather stop than hide it
                raise RecordingError(f"{rig_name} at {f:g} Hz: the streams had gaps: "
                                   f"{[(r.first_index, r.n, r.gap_samples) for r in runs]}")
            meta = {**emu.rig.metadata(), "source": f"emulated bench through the hystbench drivers, samples from "
                                                    f"{sample_source(bench_file)}"}
            recs.append(Recording(None, runs[0].fs_hz, dict(runs[0].channels), meta))
            advance()
    return recs


def run_demo(out: Path, bench_file: str | Path | None = None) -> int:
    """The demo of the module docstring into ``out``; returns 0 (a failure raises, naming its cause)."""
    console = make_console()
    out.mkdir(parents=True, exist_ok=True)
    console.rule("hystbench demo: the simulated rig, the paper's E-core sweeps")
    summary: dict = {"sweeps": {}}
    with make_progress() as progress:
        task = progress.add_task("acquiring through the drivers", total=sum(len(f) for _, _, f in SWEEPS))
        for rig_name, ipp, freqs in SWEEPS:
            recs = _sweep_through_drivers(rig_name, ipp, freqs, lambda: progress.advance(task), bench_file)
            write_sweep(recs, out / "sweeps" / rig_name, overwrite=True)

    table = Table(title=f"delays from the recordings ({DURATION_S:g} s each, 100 kS/s), degrees at f",
                  caption="paper: 0-3.3 N (ecore), 125-220 N (ecore_pm); model = the instrument's "
                          "two-filter model (Figs. 8-9)")
    for col in ("rig", "f (Hz)", "force (N)", "flux vs i", "force vs flux", "model", "force vs i"):
        table.add_column(col, justify="right", no_wrap=True)
    figures = [force_map_figure("ecore_pm", out / "force_map.png")]
    for rig_name, ipp, _ in SWEEPS:
        recs = read_sweep(out / "sweeps" / rig_name)
        instrument = presets.instrument(load_rig(rig_name))
        rows, curves = [], []
        for rec in recs:
            d = measure_delays(rec)
            i_avg, f_avg = _loop(rec, d.frequency_hz, "force_N")
            k = d.harmonic
            model_deg = -float(instrument.phase_deg(k * d.frequency_hz)) / k
            row = {"frequency_Hz": rec.frequency_hz, "force_min_N": float(f_avg.min()),
                   "force_max_N": float(f_avg.max()), "instrument_model_deg": model_deg, **d.as_dict()}
            rows.append(row)
            curves.append((f"{rec.frequency_hz:g} Hz", i_avg, f_avg))
            table.add_row(rig_name, f"{rec.frequency_hz:g}", f"{row['force_min_N']:.2f}-{row['force_max_N']:.2f}",
                          f"{d.phase_deg('hysteresis'):.3f}", f"{d.phase_deg('instrument'):.3f}",
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


def demo_sweeps(out_dir: str | Path, bench_file: str | Path | None = None) -> tuple[int, str | None]:
    """:func:`run_demo`, tolerant of the bench.  When the instruments fail (a machine too slow for
    the emulated bench at 100 kS/s: "bench: only 0 of 10000 aligned samples"; gaps in the streams),
    returns (0, why) after removing what that part writes, so no result of an earlier run is left
    looking like this one's; the demo says so and goes on with the offline part."""
    out = Path(out_dir)
    try:
        return run_demo(out, bench_file), None
    except BenchError as err:  # InstrumentError, RecordingError (gaps): the bench part failed
        shutil.rmtree(out / "sweeps", ignore_errors=True)
        for name in ["summary.json", "force_map.png", *(f"{rig}_current_force.png" for rig, _, _ in SWEEPS)]:
            (out / name).unlink(missing_ok=True)
        return 0, str(err)
