"""Measured B(t) rows (mag-net-hub's ``ploss_at_450kWpm3`` file) predicted by the loss model a
material's MagNet tables calibrate: the rate-independent loss of the excursion plus the rate terms
taken, each driven by the sampled waveform through its shape factor (the iGSE's integral of
|dB/dt|^p over the period, on the samples).

Why: those rows are held out entirely (other cores, other temperatures: 25-90 degC where the tables
are at 25 degC), so they test the model where nothing was fitted, and their residual against
temperature is where a temperature term would show.  Rows of materials without vendored tables are
counted and left out.
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from ...errors import script_status
from ...formats.material_data import WaveformTable, read_waveform_table
from .loss_separation import LN10, energy_table, log_energy, loss_table_groups, select_on_split
from .loss_terms import Rows

__all__ = ["waveform_rows", "predict_waveform_losses", "main"]


def waveform_rows(table: WaveformTable) -> tuple[Rows, np.ndarray]:
    """The rows (f, B_pk = half the peak-to-peak, temperature, B(t) / B_pk about its middle) and the
    measured energy per cycle W = P / f (J/m^3)."""
    bt = table.b_t
    hi, lo = bt.max(axis=1), bt.min(axis=1)
    bpk = (hi - lo) / 2.0
    wave = (bt - ((hi + lo) / 2.0)[:, None]) / bpk[:, None]
    return Rows(table.frequency_hz, bpk, None, table.temperature_c, wave), table.loss_w_per_m3 / table.frequency_hz


def predict_waveform_losses(waveforms: str | Path, tables: Sequence[str | Path],
                            splits: Sequence[str] = ("low_third", "interleaved")) -> list[dict[str, Any]]:
    """Per material of ``tables`` (its sine and shapes tables) and split: the waveform rows of that
    material predicted before (rate independent) and after (with the terms taken), rms log10 error, and
    the mean residual after per temperature."""
    wt = read_waveform_table(waveforms)
    rows, w = waveform_rows(wt)
    mat = np.asarray(wt.material)
    out = []
    for group in loss_table_groups(list(tables)):
        name = group[0].material
        sel = mat == name
        if not sel.any():
            continue
        f, b, wt_w, duty = energy_table(group)
        rw, y = rows.take(sel), np.log10(w[sel])
        for split in splits:
            _, seq, _, chosen, _, _ = select_on_split(Rows(f, b, duty), wt_w, split, "sine_triangle")
            rb = y - log_energy(seq[0].x, seq[0].terms, rw) / LN10
            ra = y - log_energy(seq[-1].x, seq[-1].terms, rw) / LN10
            temps = rw.temperature_c
            out.append({"material": name, "split": split, "rows": int(sel.sum()), "terms": chosen,
                        "rms_before_log10": float(np.sqrt(np.mean(rb**2))),
                        "rms_after_log10": float(np.sqrt(np.mean(ra**2))),
                        "mean_after_by_temperature_log10": {float(t): float(ra[temps == t].mean())
                                                            for t in np.unique(temps)}})
    return out


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m hystbench.analysis.diagnosis.loss_waveforms WAVEFORMS.csv TABLE.csv ...``"""
    args = list(sys.argv[1:] if argv is None else argv)
    if len(args) < 2:
        print("usage: python -m hystbench.analysis.diagnosis.loss_waveforms WAVEFORMS.csv TABLE.csv [TABLE.csv ...]",
              file=sys.stderr)
        return 2
    for r in predict_waveform_losses(args[0], args[1:]):
        temps = " ".join(f"{t:.0f}C {v:+.2f}" for t, v in r["mean_after_by_temperature_log10"].items())
        print(f"{r['material']:5s} {r['split']:11s} {r['rows']:3d} rows  {r['rms_before_log10']:.3f} -> "
              f"{r['rms_after_log10']:.3f}  {'+'.join(r['terms']) or 'none':45s} after by temperature: {temps}")
    return 0


if __name__ == "__main__":
    raise SystemExit(script_status(main))
