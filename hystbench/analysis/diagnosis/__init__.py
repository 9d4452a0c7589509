"""Diagnosis: when the simulation and a recording differ, locate the mismatch, name the physics
left out, model it and prove the fit improves (issue 13; docs/diagnosis.md).

The stages, each in its module:

0. the recordings as numbers with standard errors (:mod:`.features`, laid out by :mod:`.vector`), and
   the same numbers of the simulation: the bench day replayed on the simulated rig (:mod:`.forward`),
   as a function of calibration knobs and effects (:mod:`.columns`), fitted by :mod:`.fit`;
1. calibrate (:mod:`.calibrate`): the baseline's calibration parameters, each against its prior, and
   the explicit discrepancy of each path of the bench (:mod:`.discrepancy`: a baseline allowed to be
   wrong, issue 27);
2. locate (:mod:`.locate`): the calibrated baseline's residual as z-scores over channel pair,
   harmonic, operating point, rig and time;
3. name and 4. model (:mod:`.select`): each candidate switched on in the simulation (a frame mode
   searched first, :mod:`.search`), scored by BIC, named only when decisive and proven in its own
   signature at held-out operating points, re-simulated at its fitted values;
   and what the day can decide (:mod:`.limits`): the size from which it would be expected to name each;
5. prove (:mod:`.prove`): cross-validation over every block's operating points, held-out residual
   before and after.
Real material data (loss tables, no waveforms) take their own path: :mod:`.loss_separation`.
"""

from __future__ import annotations

import contextlib
import dataclasses
import math
import multiprocessing
import os
import time
from concurrent.futures import ProcessPoolExecutor
from typing import Any, Callable, Mapping, Sequence

import numpy as np
from threadpoolctl import threadpool_limits

from ...config import load_rig
from ...config.effects import CATALOGUE
from ...errors import BenchError, ConfigError
from ...formats.recording import Recording
from ..method import recording_name
from ..sense_coil import FLUX_FROM, with_flux
from .calibrate import calibrate, recalibrated
from .columns import Simulator, accepts, catalogue_params, check_known
from .features import RecordFeatures, record_features
from .fit import Problem, floor_scales, variance
from .forward import MEASURED_DIRECTLY, clock_follows_frequency, points_of
from .limits import detection_limits
from .locate import locate_residual
from .prove import FoldErrors, cross_validate, fold_errors, folds
from .result import Candidate, Diagnosis
from .select import DC_BLIND, MIN_HELD_OUT_GAIN, MIN_TOTAL_GAIN, candidate_effects, dc_blind, family, forward_selection, named_parameters
from .vector import CHANNELS, layout_of, line_values, values_of

__all__ = ["diagnose", "DiagnosisError", "worse_in_total"]


class DiagnosisError(BenchError, ValueError):
    """A bench day the diagnosis cannot take, named."""


def diagnose(recordings: Sequence[Recording], *, baseline: Sequence[str] | None = None,
             candidates: Sequence[str] | None = None, progress: Callable[[str], None] | None = None,
             jobs: int | None = None) -> Diagnosis:
    """Diagnose a bench day (one or several rigs' recordings); see the module docstring.  ``jobs``:
    processes replaying at once (default: $HYSTBENCH_JOBS, else one per core)."""
    start = time.perf_counter()
    say = progress or (lambda message: None)
    recs = [with_flux(r, required=False) for r in recordings]  # a sense coil's voltage, integrated
    if len(recs) < 2:
        where = recording_name(recs[0]) if recs else "the input"
        raise DiagnosisError(f"{where}: a diagnosis needs at least two recordings (operating points); got {len(recs)}")
    if baseline is not None:
        check_known(baseline, "--baseline")
    if candidates is not None:
        check_known(candidates, "--candidates")
    presets = {}
    for rec in recs:
        if rec.rig not in presets:
            try:
                presets[rec.rig] = load_rig(rec.rig)
            except ConfigError as err:
                raise DiagnosisError(f"{recording_name(rec)}: rig {rec.rig!r} is not a preset this diagnosis can "
                                     f"simulate ({err})") from err
    _check_rates(recs)
    warnings: list[str] = []
    if not any("flux_Wb" in r.channels for r in recs):
        warnings.append("no recording has flux_Wb: force vs flux and flux vs current cannot be located without it; "
                        "going on with force vs current")
    unturned = [recording_name(r) for r in recs if "sense_V" in r.channels and "flux_Wb" not in r.channels]
    if unturned:
        warnings.append(f"{len(unturned)} recording(s) have sense_V but no sense_turns in their sidecar "
                        f"({', '.join(unturned[:3])}{', ...' if len(unturned) > 3 else ''}): their sense voltage is "
                        "not integrated into a flux")

    base_effects = _baseline_effects(presets, baseline)
    in_base = sorted({e for effs in base_effects.values() for e in effs})
    # a candidate is an effect some rig's baseline lacks (the voice coil's frame modes may be known
    # while the E-cores' model leaves them out: one load cell)
    declared = {rig: set(p["effects"]) if baseline is None else set(baseline) for rig, p in presets.items()}
    lacking = {e for e in CATALOGUE for rig, p in presets.items() if accepts(rig, p, e) and e not in declared[rig]}
    if candidates is not None and (known := [e for e in candidates if e not in lacking]):
        raise ConfigError(f"--candidates: {', '.join(known)} already in every rig's baseline (or acting on none of "
                          f"the day's rigs: {', '.join(presets)}); a candidate is an effect the baseline leaves out "
                          "(see --baseline)")
    pool_names = [e for e in (candidates if candidates is not None else CATALOGUE) if e in lacking]
    fluxed = [r for r in recs if "flux_Wb" in r.channels]
    if fluxed and all(FLUX_FROM in r.metadata for r in fluxed):  # no integrator on this bench
        pool_names = [e for e in pool_names if e != "integrator_leak"]
        warnings.append("the flux was integrated by hystbench from sense_V (no flux integrator recorded): an "
                        "integrator's leak is not a candidate")
    say(f"features of {len(recs)} recordings")
    data = [_features(r) for r in recs]
    layout = layout_of(data)
    points, clocked = points_of(recs, [f.periods / f.frequency_hz for f in data],
                                [2.0 * abs(f.harmonics["current_A"][1]) for f in data])
    if not clocked:
        without = [recording_name(r) for r in recs if r.start_time_s is None]
        warnings.append("the sidecars hold no start_time_s: slow effects cannot be placed along the day"
                        if len(without) == len(recs) else
                        f"{len(without)} of {len(recs)} sidecars hold no start_time_s ({', '.join(without[:3])}"
                        f"{', ...' if len(without) > 3 else ''}): slow effects cannot be placed along the day")
    elif clock_follows_frequency(recs) and {"magnet_thermal_drift", "iron_thermal_drift"} & set(pool_names):
        warnings.append("each block's frequencies were played in order, so there the day's clock runs with the "
                        "frequency: a slow change along the day (a magnet or iron warming) looks like a smooth "
                        "frequency dependence, which the baseline's discrepancy takes; play each block's "
                        "frequencies in a shuffled order to tell them apart")
    # one BLAS thread: the fits are many small least squares, which a thread pool spread over busy
    # cores makes ten times slower (and a diagnosis is one core's work; the replays parallelise)
    with _replay_pool(jobs) as pool, threadpool_limits(limits=1, user_api="blas"):
        return _diagnose(recs, data, layout, points, presets, base_effects, in_base, pool_names, pool, start, say,
                         warnings)


def _diagnose(recs, data, layout, points, presets, base_effects, in_base, pool_names, pool, start, say,
              warnings) -> Diagnosis:
    """The stages, once the inputs are checked and the features taken (``pool_names``: the candidates)."""
    sim = Simulator(presets, base_effects, points, pool)

    d_h = values_of(data, layout)
    y_l, s_l, line_labels = line_values(data)
    d = np.concatenate([d_h, y_l])
    n_h = d_h.size

    def model_many(requests) -> list[np.ndarray]:
        return [np.concatenate([values_of(f, layout), np.zeros(y_l.size)]) for f in sim.run_many(requests)]

    say("simulating the baseline")
    m0 = model_many([(None, None)])[0]
    ok = np.isfinite(d) & np.isfinite(m0)
    ok[:n_h] &= layout.se > 0
    sigma_h = np.sqrt(variance(layout.se, layout.scale, layout.view(), layout.harmonic))
    sigma_l = np.sqrt(s_l ** 2 + 2.0 * s_l * np.maximum(y_l, 0.0))
    sigma = np.concatenate([sigma_h, sigma_l])
    problem = Problem(d, sigma, np.flatnonzero(ok), model_many, layout, np.concatenate([layout.se, s_l]),
                      np.array([r for r, _, _ in line_labels], int))

    for effect in DC_BLIND:  # an analyst's model with a leaky charge amplifier: its DC says nothing
        if any(effect in effs for effs in base_effects.values()):
            problem = dc_blind(problem, effect)
    calibration = calibrate(problem, sim, data, base_effects, m0, say)  # 1
    # the model-error floor each part of the bench day needs: as much as the calibrated baseline misses by
    scale = floor_scales(d - calibration.m0 - calibration.residual, layout, data, ok[:n_h])
    sigma_h = np.sqrt(variance(layout.se, layout.scale, layout.view(), layout.harmonic, scale))
    problem = dataclasses.replace(problem, sigma=np.concatenate([sigma_h, sigma_l]))
    calibration = dataclasses.replace(calibration, solution=problem.solve(calibration.m0, calibration.columns))
    resid_base = d - calibration.m0 - calibration.residual
    located, grid = locate_residual(data, layout, resid_base[:n_h], sigma_h, ok[:n_h], line_labels,  # 2
                                    resid_base[n_h:], sigma_l, (calibration.m0 + calibration.residual)[:n_h])
    effects = candidate_effects(problem, pool_names, presets, calibration, line_labels, say,  # 3, 4
                                [f.frequency_hz for f in data])

    def recalibrate(fit: Problem, named: Mapping[str, Mapping[str, Any]]):
        extended = fit.with_effects(named)
        return calibrate(extended, sim, data, base_effects, extended.model(), say, jacobian=calibration.jacobian)

    def judged(fit: Problem, m: np.ndarray, cols, where: np.ndarray, per_fold=None) -> FoldErrors:
        return fold_errors(fit, folds(fit, data), m, cols, fit.sigma, where, per_fold)[0]

    points = [f"{f.rig} {f.frequency_hz:.4g} Hz {f.current_pp_a:.3g} A-pp" for f in data]
    limits = detection_limits(problem, effects, calibration, points)  # before selection moves the named ones
    selection = forward_selection(problem, effects, calibration, recalibrate, judged, say)
    say("cross-validating over operating points")
    proof = cross_validate(selection.problem or problem, data, calibration, selection)  # 5

    recal = recalibrated(sim, selection.calibration, selection.solution)
    findings = [v["finding"] for v in recal.values() if v.get("finding")]
    proven = {c.name for c in selection.columns}
    findings += [_suspect_finding(c, f"generic.{c.name}" in proven) for c in selection.suspects]
    signature = {family(e.name): {"before": e.signature.before, "after": e.signature.after,
                                  "improvement": e.signature.before / e.signature.after if e.signature.after > 0 else math.inf,
                                  "numbers": e.signature.numbers, "fold_gain": e.signature.fold_gain}
                 for e in selection.named if e.signature is not None}
    findings += _direct(data, pool_names)
    names = [family(e.name) for e in selection.named]
    findings = worse_in_total(names, proof["before"], proof["after"]) + findings
    return Diagnosis(
        effect=names[0] if names else None, effects=names, candidates=selection.ranked,
        parameters={family(e.name): named_parameters(e, selection.solution) for e in selection.named},
        recalibrated=recal, located=located, residual_before=proof["before"], residual_after=proof["after"],
        noise_floor=_noise_floor(data), seconds=time.perf_counter() - start, baseline=in_base,
        candidates_considered=pool_names, findings=findings, warnings=warnings, recordings=len(recs), rigs=list(presets),
        loops=proof["loops"], grid=grid, signature=signature, suspects=list(selection.suspects),
        limits=limits)


def _suspect_finding(c: Candidate, proven: bool) -> str:
    """Why a decisive effect is a suspect: its held-out gain, or that none could be measured; ``proven``:
    what it fitted stayed in the model that is proven (it predicted no worse than without it)."""
    if c.held_out_gain is None or math.isnan(c.held_out_gain):  # no operating point where it acts was held out
        why = (f"suspect: {c.name} scores {c.score:.0f} but its signature could not be checked at held-out operating "
               f"points (none of them shows it: the day holds too few points of its rig); it is left out of the "
               "model that is proven")
    elif c.held_out_gain >= MIN_HELD_OUT_GAIN and c.held_out_total is not None and c.held_out_total < MIN_TOTAL_GAIN:
        ratio = 1 / c.held_out_total if c.held_out_total > 0 else math.inf
        worse = "infinitely" if not math.isfinite(ratio) else f"{ratio:.3g}x" if ratio < 100 else f"{ratio:.0f}x"
        why = (f"suspect: {c.name} scores {c.score:.0f} and, modelled, predicts its signature {c.held_out_gain:.2f}x "
               f"better at the median held-out fold, but {worse} worse in total (more than "
               f"{1 / MIN_TOTAL_GAIN:g}x worse refuses it: a model that breaks at some operating point); "
               "what it fitted is left out of the model that is proven (the later rounds were scored beside it)")
    else:
        why = (f"suspect: {c.name} scores {c.score:.0f} but, modelled, predicts its signature at the held-out "
               f"operating points only {c.held_out_gain:.2f}x better at the median held-out fold (at least "
               f"{MIN_HELD_OUT_GAIN:g}x names it); "
               + ("what it fitted stays in the model as a generic term, not in the catalogue" if proven else
                  "it predicts them worse (at the median fold or in total), so what it fitted is left out of the "
                  "model that is proven (the later rounds were scored beside it)"))
    return why + (f" (of what it does, {c.own_text()})" if c.own_text() else "")


def worse_in_total(names: list[str], before: float, after: float) -> list[str]:
    """A finding when the named effects, each proven in its own signature, leave the held-out operating
    points worse predicted in total (a bench unlike its simulation: what they fit is where they act)."""
    if not names or not after > before:
        return []
    return [f"the model with {', '.join(names)} predicts the held-out operating points worse in total "
            f"({before:.3g} -> {after:.3g} noise floors) although each named effect predicts its own signature "
            "better: what they explain is where they act, not the rest of the bench; weigh the names with that"]


@contextlib.contextmanager
def _replay_pool(jobs: int | None):
    """Worker processes for the replays (each is independent); None when one process must do.  They
    start from a fork server, not by forking this process, which may hold other threads' locks (a
    zenoh session, a daemon's pipeline)."""
    n = jobs if jobs is not None else int(os.environ.get("HYSTBENCH_JOBS", 0)) or (os.cpu_count() or 1)
    if n <= 1:
        yield None
        return
    with ProcessPoolExecutor(max_workers=n, mp_context=multiprocessing.get_context("forkserver")) as pool:
        yield pool


def _features(rec: Recording) -> RecordFeatures:
    """The recording's features; what they cannot take (one period, no current) as a DiagnosisError."""
    try:
        return record_features(rec)
    except ValueError as err:
        raise DiagnosisError(str(err)) from err


def _check_rates(recs: Sequence[Recording]) -> None:
    """One rig's recordings share one sample rate (one ADC setting), except a stepped sine's."""
    by_rig: dict[str, Recording] = {}
    for rec in recs:
        first = by_rig.setdefault(rec.rig, rec)
        if rec.fs_hz != first.fs_hz and "flux_Wb" in rec.channels:
            raise DiagnosisError(f"{recording_name(rec)}: sample rate {rec.fs_hz:g} Hz differs from "
                                 f"{recording_name(first)} ({first.fs_hz:g} Hz) of the same rig {rec.rig!r}; "
                                 "a bench day keeps one ADC setting per E-core rig")


def _baseline_effects(presets: Mapping[str, Mapping[str, Any]], baseline: Sequence[str] | None
                      ) -> dict[str, dict[str, dict[str, Any]]]:
    """Per rig, the effects the simulation compared has: the preset's (or exactly ``baseline``'s, those
    the rig can have), each with its parameters; noise, the ADC and mains are measured, not simulated."""
    out = {}
    for rig, p in presets.items():
        if baseline is None:
            names = [e for e in p["effects"] if e not in MEASURED_DIRECTLY]
        else:
            names = [e for e in baseline if e not in MEASURED_DIRECTLY and accepts(rig, p, e)]
        out[rig] = {e: catalogue_params(p, e) for e in names}
    return out




def _noise_floor(data: Sequence[RecordFeatures]) -> dict[str, float]:
    """Per channel, the median over recordings of the period average's noise (rms / sqrt(periods))."""
    out = {}
    for ch in CHANNELS:
        v = [f.noise_rms[ch] / math.sqrt(f.periods) for f in data if ch in f.noise_rms and math.isfinite(f.noise_rms[ch])]
        if v:
            out[ch] = float(np.median(v))
    return out


def _direct(data: Sequence[RecordFeatures], pool: Sequence[str]) -> list[str]:
    """Noise and the ADC's grid are measured, not simulated: say what the recordings show when the
    baseline leaves them out and they are among the candidates."""
    out = []
    if "sensor_noise" in pool:
        worst = {ch: float(np.median([f.noise_rms[ch] for f in data if ch in f.noise_rms])) for ch in CHANNELS
                 if any(ch in f.noise_rms for f in data)}
        out.append("sensor_noise is measured directly, not simulated: per-sample rms " +
                   ", ".join(f"{ch} {v:.3g}" for ch, v in worst.items()))
    return out


