"""A diagnosis as a person reads it: a markdown page with its figures, and a short terminal table.

The page follows the issue's stages (calibrate, locate, name, model, prove) after a one-sentence
verdict, so that the answer comes first and the evidence after it.  Everything is written into a
staging folder and moved into place only when the whole page and every figure exist
(:func:`hystbench.formats.outputs.output_folder`): an error half-way leaves nothing behind.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any, Iterable, Mapping

import numpy as np

from ..analysis.diagnosis.result import Diagnosis, Loops
from ..config.effects import CATALOGUE
from ..formats.outputs import output_folder
from .figures import plt, save_figure

__all__ = ["write_report", "render_report", "render_loss_report", "print_summary", "verdict", "plus_minus", "parameter_lines", "loops_figure", "PAGE"]

#: The page's file name inside the report folder (README: a folder viewer shows it first).
PAGE = "README.md"
HEAT_MAP = "heat_map.png"
LOOPS = "loops.png"

#: Units of preset keys by suffix (the presets' naming rule: ``fn_hz``, ``airgap_m``, ``conductivity_s_per_m``).
_UNITS = {"_hz": "Hz", "_s": "s", "_m": "m", "_t": "T", "_a": "A", "_s_per_m": "S/m", "_n_per_m": "N/m",
          "_n_per_s": "N/s", "_n_per_a": "N/A", "_k": "K"}


def unit_of(key: str) -> str:
    """A parameter's unit: the catalogue's (``effect.param``), else from a preset key's suffix
    (``instrument.fn_hz``); none for the channel gains (``gain.force_N``: relative) and the rest."""
    table, _, param = key.rpartition(".")
    spec = CATALOGUE[table].params.get(param) if table in CATALOGUE else None
    if spec is not None:
        return spec.unit
    if table == "gain":
        return ""
    match = [suffix for suffix in _UNITS if param.endswith(suffix)]
    return _UNITS[max(match, key=len)] if match else ""


def plus_minus(value: float, std: float | None) -> str:
    """``value +- std`` to the standard error's precision (one significant digit, two when it starts
    with 1), in plain or scientific notation: ``0.41 +- 0.02``, ``(3.02 +- 0.05)e-06``."""
    if value is None or not math.isfinite(value):
        return "n/a"
    if std is None or not math.isfinite(std) or std <= 0:
        return f"{value:.4g}"
    exp = int(math.floor(math.log10(abs(value)))) if value != 0 else int(math.floor(math.log10(std)))
    scale = 10.0 ** exp if (exp < -3 or exp > 4) else 1.0
    v, s = value / scale, std / scale
    lead = int(math.floor(math.log10(s)))
    decimals = max(0, -lead + (1 if f"{s:.1e}"[0] == "1" else 0))
    body = f"{v:.{decimals}f} +- {s:.{decimals}f}"
    return body if scale == 1.0 else f"({body})e{exp:+03d}"


def parameter_lines(parameters: Mapping[str, Mapping[str, tuple[float, float | None]]], no_std: str = "") -> list[str]:
    """``effect.param = value +- std unit``, one per fitted parameter, in the catalogue's names; a
    parameter without a std (None) gets ``(no_std)`` when given (why it has none)."""
    out = []
    for effect, params in parameters.items():
        for p, (v, s) in params.items():
            unit = unit_of(f"{effect}.{p}")
            why = f" ({no_std})" if no_std and s is None else ""
            out.append(f"{effect}.{p} = {plus_minus(v, s)}" + (f" {unit}" if unit else "") + why)
    return out


def verdict(d: Diagnosis) -> str:
    """The answer in one sentence."""
    proof = (f"the held-out residual falls from {_num(d.residual_before)} to {_num(d.residual_after)} noise floors "
             f"({_num(d.improvement)}x)")
    if not d.effects:
        return ("No catalogue effect is named: nothing left out explains these recordings decisively and predicts "
                "held-out operating points better (the held-out residual of the calibrated baseline is "
                f"{_num(d.residual_before)} noise floors; what it misses beyond its noise is in section 2, "
                "in the model-error floor, and in the findings).")
    names = " and ".join(f"**{e}**" for e in d.effects)
    what = "an effect" if len(d.effects) == 1 else f"{len(d.effects)} effects"
    return f"The recordings show {what} the baseline leaves out: {names}; with it modelled {proof}."


def _num(x: float | None) -> str:
    return "n/a" if x is None or not math.isfinite(x) else f"{x:.3g}"


# --- figures -----------------------------------------------------------------------------------------
def loops_figure(loops: Loops, path: Path, noise_floor: Mapping[str, float] | None = None) -> Path:
    """The held-out recording's period, measured against predicted, before and after (rows): flux vs
    current and force vs flux where flux was recorded, else force vs current; the last column is
    measured minus predicted over the period (in noise floors of the period average when known), where
    a mismatch too small to see in a loop still shows."""
    m, panels = loops.measured, []
    if "flux_Wb" in m and "current_A" in m:
        panels.append(("current_A", "flux_Wb", "current (A)", "flux (Wb)"))
    if "force_N" in m and "flux_Wb" in m:
        panels.append(("flux_Wb", "force_N", "flux (Wb)", "force (N)"))
    elif "force_N" in m and "current_A" in m:
        panels.append(("current_A", "force_N", "current (A)", "force (N)"))
    if not panels:
        raise ValueError(f"{loops.recording}: no channel pair to draw")
    judged = [ch for ch in ("flux_Wb", "force_N") if ch in m]
    floors = {ch: (noise_floor or {}).get(ch) for ch in judged}
    scaled = all(v is not None and v > 0 for v in floors.values())
    fig, axes = plt.subplots(2, len(panels) + 1, figsize=(4.6 * (len(panels) + 1), 7.2), squeeze=False)
    lims = [0.0, 0.0]  # the residual's largest |value| before, after
    for row, (label, predicted) in enumerate((("before: calibrated baseline", loops.before),
                                              ("after: with the named effects", loops.after))):
        colour = "C3" if row == 0 else "C2"
        for col, (x, y, xl, yl) in enumerate(panels):
            ax = axes[row][col]
            ax.plot(_closed(m[x]), _closed(m[y]), "k-", lw=1.6, label="measured (period average)")
            if y in predicted:
                px = predicted.get(x, m[x])
                ax.plot(_closed(px), _closed(predicted[y]), "--", color=colour, lw=1.4, label="predicted")
            ax.set_xlabel(xl)
            ax.set_ylabel(yl)
            ax.set_title(f"{label}: {yl.split(' ')[0]} vs {xl.split(' ')[0]}", fontsize=9)
            ax.ticklabel_format(axis="both", style="sci", scilimits=(-3, 4))
            ax.legend(fontsize=7, loc="best")
        ax = axes[row][-1]
        for ch, style in zip(judged, ("-", "--")):
            if ch in predicted:
                r = (np.asarray(m[ch]) - np.asarray(predicted[ch])) / (floors[ch] if scaled else 1.0)
                lims[row] = max(lims[row], float(np.max(np.abs(r))))
                ax.plot(np.append(loops.phase, loops.phase[0] + 1.0), _closed(r), style, color=colour, lw=1.2,
                        label=ch.split("_")[0])
        ax.axhline(0.0, color="grey", lw=0.6)
        ax.set_xlabel("phase (periods)")
        ax.set_ylabel("measured - predicted" + (" (noise floors)" if scaled else " (channel units)"))
        ax.set_title(f"{label.split(':')[0]}: residual over the period", fontsize=9)
        ax.legend(fontsize=7, loc="best")
    # each residual on its own scale: on the before's, a good after is a flat line that shows nothing;
    # the after's label says how much smaller its scale is, so the shrink still reads
    for row, lim in enumerate(lims):
        if lim > 0:
            axes[row][-1].set_ylim(-1.1 * lim, 1.1 * lim)
    if lims[0] > 0 and lims[1] > 0:
        ax = axes[1][-1]
        ax.set_ylabel(f"{ax.get_ylabel()}\nits own scale: {lims[1] / lims[0]:.2g} x the before's", fontsize=9)
        ax.set_title(f"{ax.get_title()} (own scale)", fontsize=9)
    fig.suptitle(f"held-out recording {loops.recording} ({loops.rig}, {loops.frequency_hz:g} Hz, "
                 f"{loops.current_pp_a:g} A-pp)", fontsize=10)
    return save_figure(fig, path)


def _closed(x: np.ndarray) -> np.ndarray:
    x = np.asarray(x, dtype=float)
    return np.append(x, x[:1])


def _heat_map(d: Diagnosis, path: Path) -> str | None:
    """The located mismatch's heat map (``reports.diagnosis_figures.heat_map``); the reason on the page
    instead when there is nothing to draw."""
    from .diagnosis_figures import heat_map

    if d.grid is None:
        return "no heat map: the diagnosis carries no located grid"
    heat_map(d.grid, path)
    return None


# --- the page ----------------------------------------------------------------------------------------
def _table(header: Iterable[str], rows: Iterable[Iterable[Any]]) -> list[str]:
    header = list(header)
    out = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    out += ["| " + " | ".join(str(c).replace("|", "\\|") for c in row) + " |" for row in rows]
    return out


def _top(axis: Any, n: int = 3) -> list[tuple[str, float]]:
    """The largest z-scores of one ``located`` axis (label -> z, label -> {z: ...} or a list of
    {label/name/value, z}); [] when the axis has another shape."""
    items: list[tuple[str, float]] = []
    if isinstance(axis, Mapping):
        for k, v in axis.items():
            z = v.get("z") if isinstance(v, Mapping) else v
            if isinstance(z, (int, float)) and not isinstance(z, bool) and math.isfinite(z):
                items.append((str(k), float(z)))
    elif isinstance(axis, list):
        for v in axis:
            if isinstance(v, Mapping) and isinstance(v.get("z"), (int, float)) and math.isfinite(v["z"]):
                label = next((v[k] for k in ("label", "name", "value", "key") if k in v), "?")
                items.append((str(label), float(v["z"])))
    return sorted(items, key=lambda t: -t[1])[:n]


def _page(d: Diagnosis, heat_map_note: str | None, loops_written: bool) -> str:
    lines = [f"# Diagnosis of {d.recordings} recordings ({', '.join(d.rigs) or 'no rig'})", "", verdict(d), ""]
    if d.warnings:
        lines += ["> **Warnings**", ">"] + [f"> - {w}" for w in d.warnings] + [""]

    lines += ["## 1. Calibration", "",
              "The baseline simulation (" + (", ".join(f"`{e}`" for e in d.baseline) or "no effects") + ") calibrated "
              "against the recordings; each parameter against its prior from the preset.", ""]
    if d.recalibrated:
        rows = []
        for key, v in d.recalibrated.items():
            unit = unit_of(key)
            prior = v.get("prior")
            rows.append((f"`{key}`", plus_minus(v.get("value"), v.get("std")) + (f" {unit}" if unit else ""),
                         "-" if prior is None else f"{prior:.4g}", v.get("finding") or ""))
        lines += _table(("parameter", "value", "preset (prior)", "finding"), rows) + [""]
    lines += (["Findings:", ""] + [f"- {f}" for f in d.findings] if d.findings
              else ["No calibration parameter is pushed far outside its prior."]) + [""]

    lines += ["## 2. Where the mismatch is", "",
              "The calibrated baseline's residual as z-scores (against each estimate's standard error and the "
              "model-error floor) over channel pair, harmonic, operating point, rig and time.", ""]
    lines += [f"![located mismatch]({HEAT_MAP})" if heat_map_note is None else f"**{heat_map_note}**", ""]
    tops = [(axis, _top(v)) for axis, v in d.located.items()]
    if any(t for _, t in tops):
        lines += _table(("axis", "largest z"), ((a, ", ".join(f"{k} ({z:.1f})" for k, z in t) or "-")
                                                for a, t in tops)) + [""]
    lines += ["<details><summary>located (JSON)</summary>", "", "```json",
              json.dumps(d.to_json()["located"], indent=1, allow_nan=False), "```", "</details>", ""]

    lines += ["## 3. Candidates, ranked", "",
              "Score: BIC of the baseline minus BIC with the candidate (its parameters fitted, the baseline "
              "recalibrated); a name needs a decisive margin over the baseline and the runner-up.  Its own: the "
              "share of what the candidate does (whitened, its most distinctive combination) that no column of "
              "the model it is scored against can make, and the group of those columns that makes most of it: "
              "an effect whose own share is a millionth cannot be told from a recalibration, whatever it scores.", ""]
    if d.candidates:
        ranked = sorted(d.candidates, key=lambda c: (c.round, -(c.score if math.isfinite(c.score) else -math.inf)))
        lines += _table(("round", "candidate", "score", "its own", "parameters"),
                        ((c.round, f"`{c.name}`" + (" **named**" if c.name in d.effects and c.round == d.effects.index(c.name) + 1 else ""),
                          _num(c.score), c.own_text() or "-", "; ".join(parameter_lines({c.name: c.parameters})) or "-")
                         for c in ranked)) + [""]
    else:
        lines += ["No candidate was scored."] + [""]

    if d.limits:
        lines += ["### What this day can decide", "",
                  "For each candidate parameter (the others off), the size from which this day would be expected "
                  "to name it: where its change, beyond what the calibrated baseline absorbs with its priors, "
                  "scores the naming margin.  Below it a \"none\" says nothing about that effect; above it the "
                  "day's own noise, the runner-up and the held-out proof still decide.  Seen most at: the operating "
                  "points that hold most of what the baseline cannot make of it (more of them lower the limit).", ""]
        lines += _table(("effect", "parameter", "decided from", "seen most at"),
                        ((f"`{lim.effect}`", lim.param, lim.bound(),
                          ", ".join(f"{k} ({100 * v:.0f} %)" for k, v in lim.seen_at) or "-") for lim in d.limits)) + [""]

    lines += ["## 4. The model", ""]
    if d.parameters:
        lines += ["The named effects' parameters, in the catalogue's names and units (`hystbench effects`):", "",
                  "```"] + parameter_lines(d.parameters) + ["```", ""]
    else:
        lines += ["Nothing named, nothing to model: no invented physics."] + [""]

    lines += ["## 5. Proof: held-out recordings", "",
              "Calibrated and fitted on part of the operating points, predicted on the others; residual of the "
              "period-averaged force and flux in units of the noise floor.", ""]
    lines += _table(("held-out residual", "noise floors"),
                    (("before (calibrated baseline)", _num(d.residual_before)),
                     ("after (with the named effects)", _num(d.residual_after)),
                     ("improvement", f"{_num(d.improvement)}x"))) + [""]
    if d.noise_floor:
        lines += ["Noise floor of the period average per channel: " +
                  ", ".join(f"{ch} {v:.3g}" for ch, v in d.noise_floor.items()), ""]
    if loops_written and d.loops is not None:
        lines += [f"![held-out loops before and after]({LOOPS})", ""]
    lines += ["---", "", f"{d.recordings} recordings, {len(d.candidates_considered)} candidates considered "
              f"({', '.join(d.candidates_considered) or 'none'}); {d.seconds:.1f} s."]
    return "\n".join(lines) + "\n"


def render_report(diagnosis: Diagnosis, folder: str | Path) -> Path:
    """The page and its figures written into ``folder`` (a staging folder: see :func:`write_report`);
    returns the page's path."""
    folder = Path(folder)
    note = _heat_map(diagnosis, folder / HEAT_MAP)
    loops = diagnosis.loops is not None
    if loops:
        loops_figure(diagnosis.loops, folder / LOOPS, diagnosis.noise_floor)
    page = folder / PAGE
    page.write_text(_page(diagnosis, note, loops), encoding="utf-8")
    return page


def write_report(diagnosis: Diagnosis, out_dir: str | Path, *, overwrite: bool = False,
                 option: str = "--report") -> Path:
    """The page and its figures in ``out_dir``, all or nothing (staged beside it, moved in when
    complete; an existing non-empty ``out_dir`` only with ``overwrite``); returns the page's path."""
    with output_folder(out_dir, overwrite=overwrite, option=option) as stage:
        page = stage.final(render_report(diagnosis, stage.path))
    return page


def render_loss_report(results: list[Mapping[str, Any]], folder: str | Path) -> Path:
    """A page for measured loss tables (``analysis.diagnosis.loss_separation``): per table the verdict,
    the named terms' parameters, the held-out error before and after, and its figure."""
    from ..analysis.diagnosis.loss_separation import SPLITS
    from .loss_figures import loss_separation_figure, loss_shapes_figure

    folder = Path(folder)
    lines = ["# Diagnosis of measured loss tables", "",
             "A rate-independent loss (energy per cycle independent of frequency, as the catalogue's "
             "static_hysteresis) is calibrated at the lowest frequencies; the rest is held out. Each table is "
             "then calibrated across the band as well, the frequencies between held out.", ""]
    for n, r in enumerate(results):
        name = Path(str(r["path"])).stem
        png = f"loss_{n}_{name}.png"
        if "shapes" in r:  # a material's sine and triangle/trapezoid tables: loss against f per shape group
            loss_shapes_figure(r.get("paths", [r["path"]]), folder / png, split=r.get("split", "low_third"), result=r)
        else:
            loss_separation_figure(r["path"], folder / png, split=r.get("split", "low_third"), result=r)
        imp = r.get("improvement")
        lines += [f"## {r.get('material') or name} ({name})", "", str(r["verdict"]) + ".", "",
                  f"Held-out rms error of log10(energy per cycle): {r['residual_before_log10']:.3f} before, "
                  f"{r['residual_after_log10']:.3f} after ({'n/a' if imp is None else f'{imp:.2f}x'}).", ""]
        o = r.get("other_split", {})
        if "refused" in o:
            lines += [f"Not calibrated across the band as well: {o['refused']}.", ""]
        elif o:  # the same library calibrated across the band, held out between
            o_imp = "n/a" if o.get("improvement") is None else f"{o['improvement']:.2f}x"
            lines += [f"Calibrated instead at the {SPLITS[o['split']]} of the frequencies ({o['split']}): "
                      f"{', '.join(o['effects']) or 'nothing'} named, held out {o['residual_before_log10']:.3f} -> "
                      f"{o['residual_after_log10']:.3f} ({o_imp}).", ""]
        for g, v in r.get("shapes", {}).get("groups", {}).items():
            lines.append(f"- {g}: {v['residual_before_log10']:.3f} -> {v['residual_after_log10']:.3f} "
                         f"({v['held_out']} held out)")
        lines += [""] if "shapes" in r else []
        params = {e: {k: (v["value"], v["std"]) for k, v in ps.items()} for e, ps in r.get("parameters", {}).items()}
        if params:
            lines += ["```"] + parameter_lines(params, no_std="not determined by the rows") + ["```", ""]
        lines += [f"![{name}]({png})", ""]
    page = folder / PAGE
    page.write_text("\n".join(lines), encoding="utf-8")
    return page


def print_summary(diagnosis: Diagnosis, console: Any) -> None:
    """A short table for the terminal: what was named, its parameters, the proof, the runner-up."""
    from rich.markup import escape
    from rich.table import Table

    d = diagnosis
    t = Table(title="diagnosis", show_header=False, title_justify="left")
    t.add_column("", style="bold", no_wrap=True)
    t.add_column("")
    t.add_row("named", escape(", ".join(d.effects)) if d.effects else "none (nothing significant left)")
    for line in parameter_lines(d.parameters):
        t.add_row("", escape(line))
    t.add_row("held-out residual", f"{_num(d.residual_before)} -> {_num(d.residual_after)} noise floors "
                                   f"({_num(d.improvement)}x)")
    for effect, sig in d.signature.items():
        median = f"median fold {_num(sig['fold_gain'])}x; " if sig.get("fold_gain") is not None else ""
        t.add_row("in its signature", f"{escape(effect)}: {_num(sig['before'])} -> {_num(sig['after'])} "
                                      f"({_num(sig['improvement'])}x; {median}{sig['numbers']:.0f} held-out numbers)")
    for c in d.suspects:
        gain = c.held_out_gain
        held = "not checked held out" if gain is None or math.isnan(gain) else f"held out {_num(gain)}x, median fold" + (
            f"; {_num(c.held_out_total)}x in total" if c.held_out_total is not None else "")
        t.add_row("suspect", f"{escape(c.name)} (score {_num(c.score)}, {held})")
    first = [c for c in d.candidates if c.round == 1 and (not d.effects or c.name != d.effects[0])]
    if first:
        best = max(first, key=lambda c: c.score if math.isfinite(c.score) else -math.inf)
        t.add_row("runner-up" if d.effects else "best candidate", f"{escape(best.name)} (score {_num(best.score)})")
    if not d.effects:  # what a "none" is worth here: the day's reach for each candidate
        for lim in d.limits:
            t.add_row("named from", escape(lim.text()))
    for f in d.findings[:3]:
        t.add_row("finding", escape(f))
    for w in d.warnings:
        t.add_row("warning", escape(w))
    t.add_row("recordings", f"{d.recordings} ({', '.join(d.rigs)}), {d.seconds:.1f} s")
    console.print(t)
