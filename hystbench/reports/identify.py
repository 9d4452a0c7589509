"""``hystbench identify`` as data: what a sweep folder says about the instrument and the iron.

Voice-coil sweeps give the instrument's two-filter model (benchmarked against the ferrite coil's
sweep when there is one, else the rig preset's model) and the magnet eddy-lag flag; E-core
sweeps give the method's delays and theta_hyst per recording.  The command line prints these
reports as tables or JSON.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Callable

from ..analysis.identification import (eddy_lag, fit_instrument, frequency_response, is_benchmark,
                                       preset_instrument, read_sweeps)
from ..analysis.method import measure_delays
from ..config import load_rig
from ..errors import RecordingError
from ..formats.recording import Recording

__all__ = ["identify_folder"]


def _instrument_report(name: str, fit, eddy, reference: str, own_is_model: bool) -> dict[str, Any]:
    out = {"kind": "instrument", "sweep": name, **fit.as_dict(),
           "points": int(fit.response.frequency_hz.size),
           "frequency_range_Hz": [float(fit.response.frequency_hz[0]), float(fit.response.frequency_hz[-1])],
           "benchmark": own_is_model, "reference": reference, "eddy": eddy.as_dict(),
           "eddy_lag_flag": eddy.significant}
    out["poorly_constrained"] = _poorly_constrained(fit)
    if not own_is_model:
        out["note"] = ("the two-filter fit above is this coil's own: it absorbs any eddy lag of its magnet, so "
                       "the instrument model is the reference's")
    return out


#: a fitted corner frequency whose standard error exceeds this fraction of it is called poorly constrained
POOR_REL_STD = 0.25
#: each corner frequency of the two-filter model, with the damping that goes with it
_CORNERS = {"fn_Hz": "zeta_n", "f0_Hz": "zeta_0"}


def _poorly_constrained(fit) -> dict[str, str]:
    """The fitted corner frequencies the sweep hardly constrains, each with why: one above the
    highest measured frequency is an extrapolation of the response's slope (its number is the fit's,
    not the sweep's); one whose uncertainty is large relative to it is not measured either."""
    f_max = float(fit.response.frequency_hz.max())
    out = {}
    for key, damping in _CORNERS.items():
        value, std = fit.params.get(key), fit.std.get(key)
        if value is None:
            continue
        if value > f_max:
            why = f"above the sweep (max {f_max:.4g} Hz)"
        elif std is not None and std > POOR_REL_STD * value:
            why = f"uncertain by {100 * std / value:.0f} % of itself"
        else:
            continue
        out[key] = f"{why}: poorly constrained ({damping} with it); a sweep beyond it would measure it"
    return out


def _ecore_report(name: str, recs: list[Recording]) -> dict[str, Any]:
    points, by_amp = [], {}
    for rec in recs:
        d = measure_delays(rec)
        points.append({"recording": d.recording, **d.as_dict(), "frequency_Hz": rec.frequency_hz,
                       "frequency_true_Hz": d.frequency_hz, "current_pp_A": rec.current_pp_a,
                       "theta_hyst_deg": d.phase_deg("hysteresis"),
                       "theta_hyst_std_deg": d.phase_std_deg("hysteresis")})
        # a list per point: an operating point played twice keeps both (the second replaced the first)
        by_amp.setdefault(f"{rec.current_pp_a:.10g}", {}).setdefault(f"{rec.frequency_hz:.10g}", []).append(
            d.phase_deg("hysteresis"))
    return {"kind": "hysteresis", "sweep": name, "rig": recs[0].rig, "points": points,
            "theta_hyst_deg_by_amplitude": by_amp}


def identify_folder(folder: str | Path, say: Callable[[str], None] = lambda text: None) -> dict[str, Any]:
    """``hystbench identify`` as data: a sweep, or a folder of sweeps, identified (one report, or
    ``{"sweeps": {name: report}}``); ``say(text)`` tells what it is doing (a progress line)."""
    sweeps = read_sweeps(folder)
    kinds = {n: load_rig(recs[0].rig).get("actuator") for n, recs in sweeps.items()}
    dropped = {n: [] for n in sweeps}
    coils, fits = {}, {}
    for n, recs in sweeps.items():
        if kinds[n] == "voicecoil":
            say(f"{n}: frequency response and instrument fit ({len(recs)} recordings)")
            coils[n] = frequency_response(recs, dropped=dropped[n])
            fits[n] = fit_instrument(coils[n])
    bench = next((n for n, r in coils.items() if is_benchmark(r.rig)), None)
    reports = {}
    for n, recs in sweeps.items():
        if kinds[n] == "voicecoil":
            if bench is not None:
                ref_model, ref = fits[bench].model, f"the {bench!r} sweep's fit"
            else:
                ref_model, ref = preset_instrument(coils[n].rig), (f"the {coils[n].rig} preset's instrument model "
                                                                   "(no ferrite sweep to benchmark against)")
            reports[n] = _instrument_report(n, fits[n], eddy_lag(coils[n], ref_model, ref), ref, n == bench)
            reports[n]["dropped_points"] = [{"recording": w, "reason": why} for w, why in dropped[n]]
        elif kinds[n] == "ecore":
            say(f"{n}: the method's delays ({len(recs)} recordings)")
            reports[n] = _ecore_report(n, recs)
        else:
            raise RecordingError(f"{folder}: sweep {n!r} is of a {kinds[n]} ({recs[0].rig}); identify takes "
                                 "voice-coil or E-core sweeps")
    return next(iter(reports.values())) if len(reports) == 1 else {"sweeps": reports}
