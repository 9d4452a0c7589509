"""Measured B(t) rows (mag-net-hub's ``ploss_at_450kWpm3`` file) predicted by the loss model a
material's MagNet tables calibrate: the rate-independent loss of the excursion plus the rate terms
taken, each driven by the sampled waveform through its shape factor (the iGSE's integral of
|dB/dt|^p over the period, on the samples).

Why: those rows are held out entirely (other cores, other temperatures: 25-90 degC where the tables
are at 25 degC), so they test the model where nothing was fitted, and their residual against
temperature is where a temperature term shows.  Rows of materials without vendored tables are
counted and left out.

The temperature step (:func:`temperature_step`): what the tables cannot say is how the loss moves
with temperature.  The library's temperature factor exp(c1 (T - 25 degC) + c2 (T - 25 degC)^2)
(``loss_terms.TEMPERATURE``, 1 at the tables' 25 degC, so it needs no offset) is fitted on the rows'
residual after the table model, taken by the same likelihood rule as every term (BIC >= 10 better
than no factor; c2 only when it is decisive on top of c1), and proven leave one temperature out: each
temperature's rows predicted by the factor selected and fitted on the other temperatures' rows alone.
"""

from __future__ import annotations

import math
import sys
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from ...errors import script_status
from ...formats.material_data import WaveformTable, read_waveform_table
from .loss_separation import LN10, NAME_DELTA_BIC, bic, energy_table, log_energy, loss_table_groups, select_on_split
from .loss_terms import T0_C, TEMPERATURE, Rows, form, natural

__all__ = ["waveform_rows", "fit_temperature_factor", "temperature_step", "predict_waveform_losses", "main"]


def waveform_rows(table: WaveformTable) -> tuple[Rows, np.ndarray]:
    """The rows (f, B_pk = half the peak-to-peak, temperature, B(t) / B_pk about its middle) and the
    measured energy per cycle W = P / f (J/m^3)."""
    bt = table.b_t
    hi, lo = bt.max(axis=1), bt.min(axis=1)
    bpk = (hi - lo) / 2.0
    wave = (bt - ((hi + lo) / 2.0)[:, None]) / bpk[:, None]
    return Rows(table.frequency_hz, bpk, None, table.temperature_c, wave), table.loss_w_per_m3 / table.frequency_hz


def fit_temperature_factor(dt: np.ndarray, resid_ln: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """The temperature factor's order selected on these rows by the likelihood rule, and fitted:
    (c1, c2), their standard errors (0 where not fitted) and the score, the BIC of no factor minus the
    chosen one's (when none is taken: the slope's, below NAME_DELTA_BIC, or -inf where untried).
    Linear least squares in ln W: the factor is exp of a polynomial in dT with no constant.  An order
    is tried only where the rows hold as many distinct temperatures away from 25 degC (one determines
    a slope, not a curvature)."""
    n = resid_ln.size
    away = np.unique(dt[dt != 0]).size
    none_bic = bic(float(resid_ln @ resid_ln), n, 0)
    best = (np.zeros(2), np.zeros(2), none_bic)
    slope_score = -math.inf
    for order in (1, 2):
        if order > away or n <= order:
            break
        a = np.column_stack([dt, dt**2])[:, :order]
        c, *_ = np.linalg.lstsq(a, resid_ln, rcond=None)
        r = resid_ln - a @ c
        rss = float(r @ r)
        score = bic(rss, n, order)
        if order == 1:
            slope_score = none_bic - score
        if best[2] - score < NAME_DELTA_BIC:
            break  # the next order is not decisive on top of what is taken
        se = np.sqrt(np.diag(np.linalg.pinv(a.T @ a)) * rss / max(n - order, 1))
        best = (np.pad(c, (0, 2 - order)), np.pad(se, (0, 2 - order)), score)
    taken = best[2] < none_bic
    return best[0], best[1], none_bic - best[2] if taken else slope_score


def temperature_step(rows: Rows, resid_ln: np.ndarray) -> dict[str, Any]:
    """The temperature factor on rows whose residual after the table model is ``resid_ln`` (ln W
    measured / modelled): selected and fitted on all rows (what is reported) and, for the proof, on
    every temperature's complement (leave one temperature out); the rms log10 error before (the table
    model) and after (times the held-out fold's factor), overall and per temperature."""
    temps = rows.temperature_c
    if temps is None or np.unique(temps[temps != T0_C]).size < 2:
        return {"skipped": f"the rows need two temperatures away from {T0_C:g} degC to hold one out"}
    dt = temps - T0_C
    c, se, score = fit_temperature_factor(dt, resid_ln)
    held = np.empty_like(resid_ln)
    for t in np.unique(temps):
        out = temps == t
        ci, _, _ = fit_temperature_factor(dt[~out], resid_ln[~out])
        held[out] = resid_ln[out] - (ci[0] * dt[out] + ci[1] * dt[out] ** 2)
    taken = score >= NAME_DELTA_BIC
    params = natural(TEMPERATURE, c, se)
    if se[1] == 0.0:  # the curvature was not taken: no figure to report for it
        del params["c2_per_K2"]
    return {"taken": taken, "score": float(score), "form": form(TEMPERATURE, params) if taken else None,
            "parameters": {k: {"value": float(v), "std": float(s)} for k, (v, s) in params.items()},
            "held_out_rms_before_log10": float(np.sqrt(np.mean(resid_ln**2))) / LN10,
            "held_out_rms_after_log10": float(np.sqrt(np.mean(held**2))) / LN10,
            "by_temperature_log10": {float(t): {"rows": int((temps == t).sum()),
                                                "mean_before": float(resid_ln[temps == t].mean() / LN10),
                                                "mean_after": float(held[temps == t].mean() / LN10)}
                                     for t in np.unique(temps)}}


def predict_waveform_losses(waveforms: str | Path, tables: Sequence[str | Path],
                            splits: Sequence[str] = ("low_third", "interleaved")) -> list[dict[str, Any]]:
    """Per material of ``tables`` (its sine and shapes tables) and split: the waveform rows of that
    material predicted before (rate independent) and after (with the terms taken), rms log10 error, the
    mean residual after per temperature, and the temperature step on that residual
    (:func:`temperature_step`)."""
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
                                                            for t in np.unique(temps)},
                        "temperature": temperature_step(rw, ra * LN10)})
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
        t = r["temperature"]
        if "skipped" in t:
            print(f"{'':24s}temperature: not fitted ({t['skipped']})")
            continue
        by = " ".join(f"{k:.0f}C {v['mean_after']:+.2f}" for k, v in t["by_temperature_log10"].items())
        print(f"{'':24s}temperature, each held out: {t['held_out_rms_before_log10']:.3f} -> "
              f"{t['held_out_rms_after_log10']:.3f}  {t['form'] or 'none taken (score %.1f)' % t['score']}  by temperature: {by}")
    return 0


if __name__ == "__main__":
    raise SystemExit(script_status(main))
