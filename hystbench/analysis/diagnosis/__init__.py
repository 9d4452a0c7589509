"""Diagnosis: when the simulation and a recording differ, locate the mismatch, name the physics
left out, model it and prove the fit improves (issue 13; docs/diagnosis.md).

The stages, each in its module:

1. calibrate (:mod:`.columns`, :mod:`.fit`): the baseline simulation's calibration parameters
   fitted to the bench day, each against its prior from the preset;
2. locate (:mod:`.locate`): the calibrated baseline's residual as z-scores over channel pair,
   harmonic, operating point, rig and time;
3. name (:func:`diagnose`): each candidate switched on in the simulation (:mod:`.forward`), its
   parameters fitted with the baseline recalibrated, scored by BIC; named only when decisive;
4. model: the named effects' parameters re-simulated at their fitted values, with standard errors;
5. prove: cross-validation over operating points, held-out residual before and after.
"""

from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from ...config import load_rig
from ...config.effects import CATALOGUE
from ...errors import BenchError, ConfigError
from ...formats.recording import Recording
from ..method import recording_name
from .columns import GAINS, KNOBS, PROBES, Probe, Simulator, _accepts, _catalogue_params, check_known
from .features import RecordFeatures, record_features
from .fit import Column, Solution, solve, variance
from .forward import MEASURED_DIRECTLY, Replayed, points_of, record_mean
from .result import Candidate, Diagnosis, Loops
from .vector import CHANNELS, VIEWS, Layout, layout_of, line_values, values_of

__all__ = ["diagnose", "DiagnosisError", "NAME_MARGIN", "RUNNER_UP_MARGIN"]

#: BIC margins that make a finding decisive: over the baseline (Kass & Raftery's "very strong") and
#: over the runner-up (so that of two look-alikes neither is named on a coin toss).
NAME_MARGIN = 10.0
RUNNER_UP_MARGIN = 6.0
MAX_ROUNDS = 3
#: A calibration parameter this many prior widths from its preset is reported as a finding.
FAR_FROM_PRIOR = 3.0
#: Re-linearise the calibration when a knob moved more than this (log factor).
RELINEARISE = 0.05
REFINE_STEPS = 3
LINE_FREQUENCIES = {50.0: (50.0, 150.0), 60.0: (60.0, 180.0)}


class DiagnosisError(BenchError, ValueError):
    """A bench day the diagnosis cannot take, named."""


@dataclass
class _Effect:
    """A candidate's columns on the full vector (harmonic rows, then line rows)."""

    name: str
    columns: list[Column]
    probes: tuple[Probe, ...] = ()
    line_hz: float | None = None
    #: a nonlinear effect's simulated change at its best grid value (its column is local to it)
    offset: np.ndarray | None = None
    at: float = 0.0  # that grid value (u); the column's coefficient adds to it


def diagnose(recordings: Sequence[Recording], *, baseline: Sequence[str] | None = None,
             candidates: Sequence[str] | None = None, progress: Callable[[str], None] | None = None) -> Diagnosis:
    """Diagnose a bench day (one or several rigs' recordings); see the module docstring."""
    start = time.perf_counter()
    say = progress or (lambda message: None)
    recs = list(recordings)
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
    warnings = _check_rates(recs)
    if not any("flux_Wb" in r.channels for r in recs):
        warnings.append("no recording has flux_Wb: force vs flux and flux vs current cannot be located without it; "
                        "going on with force vs current")

    base_effects = _baseline_effects(presets, baseline)
    in_base = sorted({e for effs in base_effects.values() for e in effs})
    # a candidate is an effect some rig's baseline lacks (the voice coil's frame modes may be known
    # while the E-cores' model leaves them out: one load cell)
    declared = {rig: set(p["effects"]) if baseline is None else set(baseline) for rig, p in presets.items()}
    lacking = {e for e in CATALOGUE for rig, p in presets.items() if _accepts(rig, p, e) and e not in declared[rig]}
    pool = [e for e in (candidates if candidates is not None else CATALOGUE) if e in lacking]
    say(f"features of {len(recs)} recordings")
    data = [_features(r) for r in recs]
    layout = layout_of(data)
    points, clocked = points_of(recs, [f.periods / f.frequency_hz for f in data])
    if not clocked:
        warnings.append("the sidecars hold no start_time_s: slow effects cannot be placed along the day")
    sim = Simulator(presets, base_effects, points, lambda reps: [_replayed_features(r) for r in reps])

    d_h = values_of(data, layout)
    y_l, s_l, line_labels = line_values(data)
    d = np.concatenate([d_h, y_l])
    n_h = d_h.size
    views = np.concatenate([layout.view(), np.full(y_l.size, "lines")])

    def model(knobs: Mapping[str, float] | None = None, effects: Mapping[str, Mapping[str, Any]] | None = None) -> np.ndarray:
        return np.concatenate([values_of(sim.run(knobs, effects), layout), np.zeros(y_l.size)])

    say("simulating the baseline")
    m0 = model()
    ok = np.isfinite(d) & np.isfinite(m0)
    ok[:n_h] &= layout.se > 0
    sigma_h = np.sqrt(variance(layout.se, layout.scale, layout.view()))
    sigma_l = np.sqrt(s_l ** 2 + 2.0 * s_l * np.maximum(y_l, 0.0))
    sigma = np.concatenate([sigma_h, sigma_l])
    rows = np.flatnonzero(ok)
    n = rows.size

    # 1. calibrate
    knobs = [k for k in KNOBS if sim.knob_applies(k)]
    x0: dict[str, float] = {}
    cal, m0 = _calibration(model, m0, knobs, x0, layout, n_h, say, data, base_effects)
    sol_cal = solve(d - m0, sigma, cal, rows)
    x1 = {k.path: x0.get(k.path, 0.0) + sol_cal.value(k.path)[0] for k in knobs}
    # re-linearise once around the calibration, held within FAR_FROM_PRIOR prior widths (a knob pushed
    # beyond them is a finding, or the sign of a missing effect: no reason to measure columns there)
    if any(abs(x1[p] - x0.get(p, 0.0)) > RELINEARISE for p in x1):
        say("re-linearising the calibration")
        x0 = {k.path: float(np.clip(x1[k.path], -FAR_FROM_PRIOR * k.prior_rel, FAR_FROM_PRIOR * k.prior_rel))
              for k in knobs}
        cal, m0 = _calibration(model, model(x0), knobs, x0, layout, n_h, say, data, base_effects)
        sol_cal = solve(d - m0, sigma, cal, rows)
    resid_base = d - m0 - sol_cal.fitted

    # 3. candidates' columns, measured around the calibrated baseline
    effects: dict[str, _Effect] = {}
    for name in pool:
        if name in ("sensor_noise", "adc_quantisation"):
            continue
        if name == "mains_pickup":
            for f0, pair in LINE_FREQUENCIES.items():
                effects[f"mains_pickup@{f0:g}"] = _mains(f0, pair, line_labels, n_h, d.size)
            continue
        probes = tuple(p for p in PROBES[name] if any(_accepts(r, presets[r], name) for r in presets))
        if not probes:
            continue
        say(f"switching on {name}")
        if len(probes) == 1 and probes[0].grid:
            eff = _grid_effect(name, probes[0], model, x0, m0, d, sigma, cal, rows)
        else:
            cols = []
            for pr in probes:
                m = model(x0, {name: pr.setting(pr.probe)})
                cols.append(Column(f"{name}.{pr.param}", (m - m0) / pr.probe, lower=pr.lower))
            eff = _Effect(name, cols, probes)
        if any(np.any(np.abs(c.values[rows]) > 0) for c in eff.columns):
            effects[name] = eff

    named: list[_Effect] = []
    ranked_all: list[Candidate] = []
    m_named = m0  # the model with the named effects at their fitted values (linearised around them)
    sol = solve(d - m_named, sigma, cal, rows)
    for rnd in range(1, MAX_ROUNDS + 1):
        base_cols = cal + [c for e in named for c in e.columns]
        scores = []
        for key, eff in effects.items():
            if any(_family(key) == _family(e.name) for e in named):
                continue
            m_e = m_named if eff.offset is None else m_named + eff.offset
            sol_e = solve(d - m_e, sigma, base_cols + eff.columns, rows)
            delta = (sol.chi2 + sol.chi2_prior) - (sol_e.chi2 + sol_e.chi2_prior) - len(eff.columns) * math.log(n)
            scores.append((delta, key, sol_e))
        scores = _best_per_family(scores)
        scores.sort(key=lambda s: -s[0])
        for delta, key, sol_e in scores:
            ranked_all.append(Candidate(_family(key), float(delta), _parameters(effects[key], sol_e), rnd))
        if not scores:
            break
        top = scores[0]
        runner = scores[1][0] if len(scores) > 1 else -math.inf
        if not (top[0] >= NAME_MARGIN and top[0] - runner >= RUNNER_UP_MARGIN):
            say(f"round {rnd}: nothing decisive (best {_family(top[1])} {top[0]:.1f}, runner-up {runner:.1f})")
            break
        say(f"round {rnd}: {_family(top[1])} (score {top[0]:.1f}, runner-up {runner:.1f}); re-simulating it")
        eff = effects[top[1]]
        if eff.offset is not None:  # its change joins the model; its column stays local to it
            m_named = m_named + eff.offset
        named.append(eff)
        # 4. model: re-simulate at the fitted values and refit around them (Gauss-Newton)
        m_named, sol = _refine(model, named, knobs, x0, cal, m_named, d, sigma, rows)

    parameters: dict[str, dict[str, tuple[float, float]]] = {}
    m0_final = m_named
    for e in named:
        parameters[_family(e.name)] = _parameters(e, sol)

    # 2. locate (on the calibrated baseline), reported before the naming it guided
    located, grid = _locate(data, layout, resid_base[:n_h], sigma_h, ok[:n_h], line_labels, resid_base[n_h:], sigma_l)

    # 5. prove
    say("cross-validating over operating points")
    proof = _prove(data, layout, d, m0, m0_final, sigma, rows, cal, named, n_h)

    recal = _recalibrated(sim, knobs, x0, sol, cal)
    findings = [v["finding"] for v in recal.values() if v.get("finding")]
    findings += _direct(data, base_effects, pool)
    names = [_family(e.name) for e in named]
    seconds = time.perf_counter() - start
    return Diagnosis(
        effect=names[0] if names else None, effects=names, candidates=ranked_all, parameters=parameters,
        recalibrated=recal, located=located, residual_before=proof["before"], residual_after=proof["after"],
        noise_floor=_noise_floor(data), seconds=seconds, baseline=in_base, candidates_considered=pool,
        findings=findings, warnings=warnings, recordings=len(recs), rigs=list(presets), loops=proof["loops"],
        grid=grid)


def _features(rec: Recording) -> RecordFeatures:
    try:
        return record_features(rec)
    except ValueError as err:
        raise DiagnosisError(str(err)) from err


def _replayed_features(rep: Replayed) -> RecordFeatures:
    """A replayed point's features: the middle window's harmonics, each channel's DC the record's mean
    (the quadratic through the start, middle and end windows), as the recording's features hold it."""
    f = _features(rep.middle)
    if rep.edges is None:
        return f
    first, last = (_features(w) for w in rep.edges)
    # a window's DC is the mean of its whole periods, which start at its first sample
    centres = [w.start_time_s + 0.5 * g.periods / g.frequency_hz
               for w, g in ((rep.edges[0], first), (rep.middle, f), (rep.edges[1], last))]
    harmonics = {}
    for ch, h in f.harmonics.items():
        h = h.copy()
        h[0] = record_mean([first.harmonics[ch][0].real, h[0].real, last.harmonics[ch][0].real], centres, rep.span)
        harmonics[ch] = h
    return dataclasses.replace(f, harmonics=harmonics)


def _check_rates(recs: Sequence[Recording]) -> list[str]:
    """One rig's recordings share one sample rate (one ADC setting), except a stepped sine's."""
    by_rig: dict[str, Recording] = {}
    for rec in recs:
        first = by_rig.setdefault(rec.rig, rec)
        if rec.fs_hz != first.fs_hz and "flux_Wb" in rec.channels:
            raise DiagnosisError(f"{recording_name(rec)}: sample rate {rec.fs_hz:g} Hz differs from "
                                 f"{recording_name(first)} ({first.fs_hz:g} Hz) of the same rig {rec.rig!r}; "
                                 "a bench day keeps one ADC setting per E-core rig")
    return []


def _baseline_effects(presets: Mapping[str, Mapping[str, Any]], baseline: Sequence[str] | None
                      ) -> dict[str, dict[str, dict[str, Any]]]:
    out = {}
    for rig, p in presets.items():
        if baseline is None:
            names = [e for e in p["effects"] if e not in MEASURED_DIRECTLY]
        else:
            names = [e for e in baseline if e not in MEASURED_DIRECTLY and _accepts(rig, p, e)]
        out[rig] = {e: _catalogue_params(p, e) for e in names}
    return out


def _calibration(model, m0: np.ndarray, knobs, x0: Mapping[str, float], layout: Layout, n_h: int,
                 say, data, base_effects) -> tuple[list[Column], np.ndarray]:
    cols = []
    for k in knobs:
        say(f"calibration: {k.path}")
        h = 0.02
        x = dict(x0)
        x[k.path] = x0.get(k.path, 0.0) + h
        cols.append(Column(k.path, (model(x) - m0) / h, prior=k.prior_rel))
    cols += _static_loop_columns(data, base_effects, layout, m0)
    for name, (channel, width) in GAINS.items():
        mask = np.zeros(m0.size, bool)
        mask[:n_h] = layout.channel == CHANNELS.index(channel)
        if np.any(mask):
            cols.append(Column(name, np.where(mask, m0, 0.0), prior=width))
    return cols, m0


def _refine(model, named, knobs, x0, cal, m_lin, d, sigma, rows) -> tuple[np.ndarray, Solution]:
    """Gauss-Newton on the calibration and the named effects: each step re-simulates at the fitted
    values; the columns stay those measured (the model's change at the fitted values is exact, its
    slope approximate).  Stops when no named parameter moves by 0.3 of its standard error."""
    effect_cols = [c for e in named for c in e.columns]
    moved = [c for c in cal if c.name not in GAINS] + effect_cols
    sol = solve(d - m_lin, sigma, cal + effect_cols, rows)
    for _ in range(REFINE_STEPS):
        x_fit = {k.path: x0.get(k.path, 0.0) + sol.value(k.path)[0] for k in knobs}
        eff_params = _effect_params(named, sol)
        if not eff_params:
            break
        m1 = model(x_fit, eff_params)
        m_new = m1 - sum(c.values * sol.value(c.name)[0] for c in moved)
        new = solve(d - m_new, sigma, cal + effect_cols, rows)
        step = max(abs(new.value(c.name)[0] - sol.value(c.name)[0]) / max(new.value(c.name)[1], 1e-300)
                   for c in effect_cols)
        sol, m_lin = new, m_new
        if step < 0.3:
            break
    return m_lin, sol


def _effect_params(named: Sequence[_Effect], sol: Solution) -> dict[str, dict[str, Any]]:
    """The named effects' catalogue parameters at the fitted values, kept inside their ranges."""
    out = {}
    for e in named:
        if e.probes:
            merged: dict[str, Any] = dict(e.probes[0].fixed)
            for pr in e.probes:
                merged.update(pr.params(max(e.at + sol.value(f"{e.name}.{pr.param}")[0], pr.lower)))
            out[e.name] = _clamp(e.name, merged)
    return out


def _clamp(effect: str, params: Mapping[str, Any]) -> dict[str, Any]:
    out = dict(params)
    for k, v in params.items():
        key = CATALOGUE[effect].params.get(k)
        if key is None or not isinstance(v, (int, float)):
            continue
        lo = key.ge if key.ge is not None else key.gt
        hi = key.le if key.le is not None else key.lt
        if lo is not None and v <= lo:
            v = lo if key.ge is not None else lo + 1e-12 * max(1.0, abs(lo))
        if hi is not None and v >= hi:
            v = hi if key.le is not None else hi - 1e-12 * max(1.0, abs(hi))
        out[k] = v
    return out


def _grid_effect(name: str, probe: Probe, model, x0, m0: np.ndarray, d: np.ndarray, sigma: np.ndarray,
                 cal: list[Column], rows: np.ndarray) -> _Effect:
    """A nonlinear candidate: simulated at each grid value, the calibration re-solved each time; the
    best value's change is the offset and a local column (a 20 % step) refines it."""
    best = None
    for u in probe.grid:
        change = model(x0, {name: probe.setting(u)}) - m0
        chi2 = solve(d - m0 - change, sigma, cal, rows).chi2
        if best is None or chi2 < best[0]:
            best = (chi2, u, change)
    _, u, change = best
    h = 0.2 * u
    local = (model(x0, {name: probe.setting(u + h)}) - m0 - change) / h
    return _Effect(name, [Column(f"{name}.{probe.param}", local, lower=-u)], (probe,), offset=change, at=u)


#: Prior width of the static loop's recalibration, as a share of the channel's largest harmonic.
STATIC_LOOP_PRIOR = 0.05


def _static_loop_columns(data, base_effects, layout: Layout, m0: np.ndarray) -> list[Column]:
    """The baseline's static hysteresis, recalibrated without a form: at each rig and amplitude, each
    harmonic of the flux and of the force may move by one complex number, the same at every frequency.
    A real iron's loop is never the preset material's; what the rig's other physics does with
    frequency (eddy currents, the instrument, the channels' filters and delays) stays for the
    candidates to explain.  Only for rigs whose baseline has ``static_hysteresis``."""
    cols = []
    groups: dict[tuple[str, float], list[int]] = {}
    for r, f in enumerate(data):
        if "static_hysteresis" in base_effects.get(f.rig, {}):
            groups.setdefault((f.rig, round(f.current_pp_a, 6)), []).append(r)
    for (rig, amp), recs in groups.items():
        in_group = np.isin(layout.record, recs)
        for ch in ("flux_Wb", "force_N"):
            ci = CHANNELS.index(ch)
            for k in range(int(layout.harmonic.max(initial=0)) + 1):
                for part in (0, 1):
                    sel = in_group & (layout.channel == ci) & (layout.harmonic == k) & (layout.part == part)
                    if not sel.any():
                        continue
                    v = np.zeros(m0.size)
                    v[np.flatnonzero(sel)] = 1.0
                    scale = float(np.max(layout.scale[in_group & (layout.channel == ci)]))
                    cols.append(Column(f"static_loop.{rig}@{amp:g}A.{ch}.k{k}.{'im' if part else 're'}", v,
                                       prior=STATIC_LOOP_PRIOR * scale))
    return cols


def _mains(f0: float, pair: tuple[float, float], labels, n_h: int, size: int) -> _Effect:
    cols = []
    for ch in ("force_N", "sense_V"):
        for hz, what in zip(pair, ("fundamental", "third")):
            v = np.zeros(size)
            for j, (_, c, line) in enumerate(labels):
                if c == ch and line == hz:
                    v[n_h + j] = 1.0
            if v.any():
                cols.append(Column(f"mains_pickup@{f0:g}.{ch}.{what}", v, lower=0.0))
    return _Effect(f"mains_pickup@{f0:g}", cols, line_hz=f0)


def _family(key: str) -> str:
    return key.split("@")[0]


def _best_per_family(scores):
    best: dict[str, tuple] = {}
    for s in scores:
        f = _family(s[1])
        if f not in best or s[0] > best[f][0]:
            best[f] = s
    return list(best.values())


def _parameters(eff: _Effect, sol: Solution) -> dict[str, tuple[float, float]]:
    """A candidate's fitted parameters in the catalogue's names and units."""
    if eff.line_hz is not None:
        power = {c.name.split(".", 1)[1]: sol.value(c.name) for c in eff.columns}
        out = {"frequency_hz": (eff.line_hz, 0.0)}
        for ch, key in (("force_N", "force_n"), ("sense_V", "sense_v")):
            p, s = power.get(f"{ch}.fundamental", (math.nan, math.nan))
            if math.isfinite(p):
                a = math.sqrt(max(p, 0.0))
                out[key] = (a, s / (2 * a) if a > 0 else math.sqrt(s))
        pf, sf = power.get("force_N.fundamental", (math.nan, math.nan))
        p3, s3 = power.get("force_N.third", (math.nan, math.nan))
        if pf > 0 and math.isfinite(p3):
            r = math.sqrt(max(p3, 0.0) / pf)
            out["third_harmonic"] = (r, 0.5 * r * math.hypot(s3 / max(p3, 1e-300), sf / pf) if r > 0 else math.nan)
        return out
    out = {}
    for pr in eff.probes:
        u, su = sol.value(f"{eff.name}.{pr.param}")
        u += eff.at
        out[pr.param] = (pr.value(u), abs(pr.derivative(u)) * su if math.isfinite(pr.value(u)) else math.nan)
    return out


def _recalibrated(sim: Simulator, knobs, x0, sol: Solution, cal: list[Column]) -> dict[str, dict[str, Any]]:
    """Each calibration parameter's value, standard error and prior; a finding where the data pushed
    it beyond FAR_FROM_PRIOR prior widths."""
    out: dict[str, dict[str, Any]] = {}
    for k in knobs:
        x, sx = x0.get(k.path, 0.0) + sol.value(k.path)[0], sol.value(k.path)[1]
        prior, value = sim.knob_value(k), sim.knob_value(k, x)
        entry: dict[str, Any] = {"value": value, "std": sx if k.linear else value * sx, "prior": prior,
                                 "prior_rel": k.prior_rel}
        if abs(x) > FAR_FROM_PRIOR * k.prior_rel:
            how = (f"{value:.4g} instead of the preset's {prior:.4g}" if k.linear else
                   f"{math.exp(x):.2g}x the preset's ({prior:.4g} -> {value:.4g})")
            entry["finding"] = f"{k.path} is {how}, {abs(x) / k.prior_rel:.1f} prior widths away"
            if k.needs and not k.linear:
                entry["finding"] += f": {k.needs} is {'stronger' if x > 0 else 'weaker'} than the preset says"
        out[k.path] = entry
    loop = [c for c in cal if c.name.startswith("static_loop.")]
    for c in cal:
        if c.name in GAINS:
            g, s = sol.value(c.name)
            entry = {"value": 1.0 + g, "std": s, "prior": 1.0, "prior_rel": c.prior}
            if abs(g) > FAR_FROM_PRIOR * (c.prior or 1.0):
                entry["finding"] = f"{c.name}: the channel reads {1 + g:.3g}x what the preset's sensitivity says"
            out[c.name] = entry
    if loop:
        shares = [abs(sol.value(c.name)[0]) / (c.prior / STATIC_LOOP_PRIOR) for c in loop]
        worst = int(np.argmax(shares))
        entry = {"value": shares[worst], "std": None, "prior": 0.0, "prior_rel": STATIC_LOOP_PRIOR,
                 "where": loop[worst].name, "parameters": len(loop)}
        if shares[worst] > FAR_FROM_PRIOR * STATIC_LOOP_PRIOR:
            entry["finding"] = (f"static_hysteresis: the loop differs from the preset material's by up to "
                                f"{100 * shares[worst]:.1f} % of the channel ({loop[worst].name})")
        out["static_hysteresis.loop"] = entry
    return out


def _get(preset, path):
    node = preset
    for part in path.split("."):
        if not isinstance(node, Mapping) or part not in node:
            return None
        node = node[part]
    return float(node)


def _noise_floor(data: Sequence[RecordFeatures]) -> dict[str, float]:
    """Per channel, the median over recordings of the period average's noise (rms / sqrt(periods))."""
    out = {}
    for ch in CHANNELS:
        v = [f.noise_rms[ch] / math.sqrt(f.periods) for f in data if ch in f.noise_rms and math.isfinite(f.noise_rms[ch])]
        if v:
            out[ch] = float(np.median(v))
    return out


def _direct(data: Sequence[RecordFeatures], base_effects, pool: Sequence[str]) -> list[str]:
    """Noise and the ADC's grid are measured, not simulated: say what the recordings show when the
    baseline leaves them out and they are among the candidates."""
    out = []
    if "sensor_noise" in pool:
        worst = {ch: float(np.median([f.noise_rms[ch] for f in data if ch in f.noise_rms])) for ch in CHANNELS
                 if any(ch in f.noise_rms for f in data)}
        out.append("sensor_noise is measured directly, not simulated: per-sample rms " +
                   ", ".join(f"{ch} {v:.3g}" for ch, v in worst.items()))
    return out


def _reconstruct(values: np.ndarray, layout: Layout, record: int) -> dict[str, np.ndarray]:
    """Complex harmonics per channel of one record from the vector's rows."""
    out: dict[str, np.ndarray] = {}
    K = int(layout.harmonic.max(initial=0))
    for ci, ch in enumerate(CHANNELS):
        sel = (layout.record == record) & (layout.channel == ci)
        if not sel.any():
            continue
        h = np.zeros(K + 1, complex)
        for v, k, p in zip(values[: layout.size][sel], layout.harmonic[sel], layout.part[sel]):
            h[k] += v if p == 0 else 1j * v
        out[ch] = h
    return out


def _period(h: np.ndarray, phase: np.ndarray) -> np.ndarray:
    k = np.arange(h.size)
    return (h[None, :] * np.exp(2j * np.pi * np.outer(phase, k))).real @ np.ones(h.size) - 0.0


def _prove(data, layout: Layout, d, m0, m0_final, sigma, rows, cal, named, n_h) -> dict[str, Any]:
    """Cross-validation over operating points: fold = one excitation frequency of the E-core rigs
    (the voice coil's instrument sweep always trains); held-out residual of the flux and force
    harmonics in units of their standard errors."""
    recs_ecore = sorted({r for r, f in enumerate(data) if "flux_Wb" in f.harmonics})
    group = {r: round(data[r].frequency_hz) for r in recs_ecore} or {r: r for r in range(len(data))}
    folds = sorted(set(group.values()))
    if len(folds) < 2:
        group = {r: r for r in group}
        folds = sorted(set(group.values()))
    harmonic_rows = rows[rows < n_h]
    rec_of = layout.record[harmonic_rows]
    chan_of = layout.channel[harmonic_rows]
    judged = np.isin(chan_of, [CHANNELS.index("flux_Wb"), CHANNELS.index("force_N")])
    before_num = after_num = den = 0.0
    pred_before = np.full(d.size, np.nan)
    pred_after = np.full(d.size, np.nan)
    named_cols = [c for e in named for c in e.columns]
    for g in folds:
        test_recs = [r for r, gg in group.items() if gg == g]
        test = harmonic_rows[np.isin(rec_of, test_recs) & judged]
        train = np.setdiff1d(rows, harmonic_rows[np.isin(rec_of, test_recs)])
        if test.size == 0 or train.size == 0:
            continue
        sb = solve(d - m0, sigma, cal, train)
        pred_before[test] = m0[test] + sb.fitted[test]
        sa = solve(d - m0_final, sigma, cal + named_cols, train) if named else sb
        base_a = m0_final if named else m0
        pred_after[test] = base_a[test] + sa.fitted[test]
        se2 = layout.se[test] ** 2
        before_num += float(np.sum((d[test] - pred_before[test]) ** 2))
        after_num += float(np.sum((d[test] - pred_after[test]) ** 2))
        den += float(np.sum(se2))
    before = math.sqrt(before_num / den) if den > 0 else math.nan
    after = math.sqrt(after_num / den) if den > 0 else math.nan
    loops = None
    tested = np.flatnonzero(np.isfinite(pred_before[:n_h]))
    if tested.size:
        err = {}
        for i in tested:
            r = int(layout.record[i])
            err[r] = err.get(r, 0.0) + ((d[i] - pred_before[i]) / layout.se[i]) ** 2
        worst = max(err, key=err.get)
        phase = np.linspace(0.0, 1.0, 256, endpoint=False)
        f = data[worst]
        meas = _reconstruct(np.where(np.isfinite(pred_before), d, np.nan), layout, worst)
        bef = _reconstruct(pred_before, layout, worst)
        aft = _reconstruct(pred_after, layout, worst)
        loops = Loops(f.name, f.rig, f.frequency_hz, f.current_pp_a, phase,
                      {c: _period(np.nan_to_num(h), phase) for c, h in meas.items()},
                      {c: _period(np.nan_to_num(h), phase) for c, h in bef.items()},
                      {c: _period(np.nan_to_num(h), phase) for c, h in aft.items()})
        cur = _reconstruct(d, layout, worst).get("current_A")
        if cur is not None:
            for part in (loops.measured, loops.before, loops.after):
                part["current_A"] = _period(np.nan_to_num(cur), phase)
    return {"before": before, "after": after, "loops": loops}


def _locate(data, layout: Layout, resid: np.ndarray, sigma_h: np.ndarray, ok: np.ndarray, line_labels, resid_l, sigma_l):
    """The calibrated baseline's residual as locate's entries: per record, view and harmonic."""
    try:
        from .locate import ResidualEntry, locate
    except ImportError:  # TEMPORARY until locate lands
        return {}, None

    entries = []
    z2 = np.where(ok, (resid / sigma_h) ** 2, np.nan)
    for r, f in enumerate(data):
        for ci, ch in enumerate(CHANNELS):
            for k in range(int(layout.harmonic.max(initial=0)) + 1):
                sel = (layout.record == r) & (layout.channel == ci) & (layout.harmonic == k) & ok
                if sel.any():
                    entries.append(ResidualEntry(r, f.rig, f.frequency_hz, f.current_pp_a, f.start_time_s, ch,
                                                 VIEWS[ch], str(k), float(np.sum(z2[sel])), int(sel.sum())))
    for j, (r, ch, hz) in enumerate(line_labels):
        if np.isfinite(resid_l[j]) and sigma_l[j] > 0:
            f = data[r]
            entries.append(ResidualEntry(r, f.rig, f.frequency_hz, f.current_pp_a, f.start_time_s, ch, "alone",
                                         f"line {hz:g} Hz", float((resid_l[j] / sigma_l[j]) ** 2), 1))
    located = locate(entries)
    return located.to_json(), located
