"""Where the simulation and the recording differ: the residual's chi-square mapped over channel
pair, harmonic, operating point, rig and time, each cell as a z-score.

The caller hands a table of chi-square contributions (residual over standard error, squared and
summed, with the model-error floor already in the standard errors); every cell of every map is the
chi-square's standard score z = (sum chi2 - sum dof) / sqrt(2 sum dof): 0 when the residual is
noise, a few units by chance, tens where the model leaves something out.  Summing chi-squares
before scoring lets a small mismatch spread over many records stand out as it should.
"""

from __future__ import annotations

import math
from collections import defaultdict
from dataclasses import dataclass, field
from typing import Any, Callable, Hashable, Iterable, Sequence

import numpy as np

from .vector import CHANNELS
from .vector import VIEWS as CHANNEL_VIEWS

__all__ = ["VIEWS", "ResidualEntry", "Located", "locate", "locate_residual", "chi2_z"]

#: The channel pairs (and channels alone), in the order a reader expects them.
VIEWS = ("flux vs current", "force vs flux", "force vs current", "current vs command", "alone")


@dataclass(frozen=True)
class ResidualEntry:
    """One cell of the residual: a record's channel in one view at one harmonic (or line)."""

    record: int
    rig: str
    frequency_hz: float
    current_pp_a: float
    start_time_s: float | None
    channel: str
    view: str
    harmonic: str  # "0", "1", ... or "line 50 Hz"
    chi2: float
    dof: int


def chi2_z(chi2: float, dof: int) -> float:
    """The chi-square's standard score (its mean dof, its variance 2 dof under the model); 0 for no dof."""
    return (chi2 - dof) / math.sqrt(2.0 * dof) if dof > 0 else 0.0


def _view_label(e: ResidualEntry) -> str:
    return f"{e.channel} alone" if e.view == "alone" else e.view


def _view_key(label: str) -> tuple:
    view = "alone" if label.endswith(" alone") else label
    return (VIEWS.index(view) if view in VIEWS else len(VIEWS), label)


def _harmonic_key(label: str) -> tuple:
    if label.isdigit():
        return (0, int(label), label)
    if label.startswith("line ") and label.endswith(" Hz"):
        try:
            return (1, float(label[5:-3]), label)
        except ValueError:
            pass
    return (2, 0.0, label)


def _rounded(x: float) -> float:
    """An operating point as a reader names it: 120.003 Hz (the estimated frequency) is 120 Hz."""
    return float(f"{x:.4g}")


def _cells(entries: Iterable[ResidualEntry], key: Callable[[ResidualEntry], Hashable]) -> dict[Hashable, list[float]]:
    sums: dict[Hashable, list[float]] = defaultdict(lambda: [0.0, 0])
    for e in entries:
        s = sums[key(e)]
        s[0] += e.chi2
        s[1] += e.dof
    return sums


def _cell(name: str, label: Any, chi2: float, dof: int) -> dict[str, Any]:
    return {name: label, "z": round(chi2_z(chi2, dof), 3), "chi2": round(float(chi2), 6), "dof": int(dof)}


@dataclass(frozen=True)
class Located:
    """The residual mapped over each axis (``to_json``), its strongest cells (``top``) and the
    record-by-cell map a heat map draws (``grid``)."""

    entries: tuple[ResidualEntry, ...]
    floor_note: str = ""
    _json: dict[str, Any] = field(default_factory=dict, repr=False)

    def to_json(self) -> dict[str, Any]:
        """``channels``, ``harmonics``, ``frequencies_Hz``, ``amplitudes_pp_A``, ``rigs``, ``time``:
        lists of {label or value, z, chi2, dof}; ``time`` per rig (z of the excess's slope along
        start_time_s, first and last start).  NaN-free."""
        return self._json

    def top(self, n: int = 3) -> list[dict[str, Any]]:
        """The ``n`` strongest cells (view x harmonic x rig), strongest first, each with a sentence
        such as "force vs flux, harmonic 0, ecore_pm: z = 41"."""
        cells = _cells(self.entries, lambda e: (_view_label(e), e.harmonic, e.rig))
        ranked = sorted(((chi2_z(c, d), k, c, d) for k, (c, d) in cells.items()), key=lambda t: -t[0])
        out = []
        for z, (view, harm, rig), c, d in ranked[:max(0, int(n))]:
            where = f"harmonic {harm}" if harm.isdigit() else harm
            out.append({"view": view, "harmonic": harm, "rig": rig, "z": round(z, 3), "chi2": round(c, 6),
                        "dof": int(d), "text": f"{view}, {where}, {rig}: z = {_z_text(z)}"})
        return out

    def grid(self) -> tuple[list[str], list[str], np.ndarray]:
        """(row labels: view x harmonic; column labels: the records in sweep order, by start_time_s,
        then rig, frequency, amplitude; z per cell, NaN where the record has no such cell)."""
        rows = sorted({(_view_label(e), e.harmonic) for e in self.entries},
                      key=lambda vh: (_view_key(vh[0]), _harmonic_key(vh[1])))
        recs = {e.record: e for e in self.entries}
        order = sorted(recs, key=lambda r: _record_key(recs[r]))
        ri = {vh: i for i, vh in enumerate(rows)}
        ci = {r: j for j, r in enumerate(order)}
        z = np.full((len(rows), len(order)), math.nan)
        for (view, harm, r), (c, d) in _cells(self.entries, lambda e: (_view_label(e), e.harmonic, e.record)).items():
            z[ri[(view, harm)], ci[r]] = chi2_z(c, d)
        row_labels = [f"{v}, k={h}" if h.isdigit() else f"{v}, {h}" for v, h in rows]
        col_labels = [_record_label(recs[r]) for r in order]
        return row_labels, col_labels, z


def _z_text(z: float) -> str:
    """57.7, 4.33, 1623: three figures, never an exponent."""
    return f"{z:.0f}" if abs(z) >= 100 else f"{z:.3g}"


def _record_key(e: ResidualEntry) -> tuple:
    t = e.start_time_s
    return (t is None, t if t is not None else 0.0, e.rig, e.frequency_hz, e.current_pp_a, e.record)


def _record_label(e: ResidualEntry) -> str:
    return f"{e.rig} {_rounded(e.frequency_hz):g} Hz {e.current_pp_a:g} A"


def _time_trend(entries: list[ResidualEntry]) -> list[dict[str, Any]]:
    """Per rig: the weighted regression of each record's chi-square excess on its start time.

    Under the model a record's excess (chi2 - dof) has variance 2 dof, hence the weights; where the
    excess scatters more than that (a mismatch present everywhere), the slope's SE is scaled by
    the scatter, so only a trend along the sweep scores, not a uniform offset."""
    out = []
    for rig in _rigs_in_order(entries):
        per = _cells((e for e in entries if e.rig == rig), lambda e: e.record)
        times = {e.record: e.start_time_s for e in entries if e.rig == rig}
        chi2, dof = sum(c for c, _ in per.values()), int(sum(d for _, d in per.values()))
        item = {"label": rig, "z": None, "chi2": round(float(chi2), 6), "dof": dof, "first_s": None, "last_s": None,
                "records": len(per)}
        timed = [(times[r], c - d, 2.0 * d) for r, (c, d) in per.items() if times[r] is not None and d > 0]
        if len(timed) < len(per) or not timed:
            item["note"] = "no start_time_s"
            out.append(item)
            continue
        t, ex, var = (np.array(v, float) for v in zip(*timed))
        item["first_s"], item["last_s"] = float(t.min()), float(t.max())
        if len(t) < 2 or np.ptp(t) == 0:
            item["note"] = "one start time: no trend"
            out.append(item)
            continue
        w = 1.0 / var
        tc = t - np.sum(w * t) / np.sum(w)
        sxx = float(np.sum(w * tc ** 2))
        slope = float(np.sum(w * tc * ex) / sxx)
        intercept = float(np.sum(w * ex) / np.sum(w))
        scatter = float(np.sum(w * (ex - intercept - slope * tc) ** 2) / (len(t) - 2)) if len(t) > 2 else 1.0
        se = math.sqrt(max(1.0, scatter) / sxx)
        item["z"] = round(slope / se, 3)
        item["slope_per_s"] = slope
        out.append(item)
    return out


def _rigs_in_order(entries: list[ResidualEntry]) -> list[str]:
    """Rigs in the order of the sweep (their first record's start time, else their first record)."""
    first: dict[str, tuple] = {}
    for e in entries:
        key = _record_key(e)
        if e.rig not in first or key < first[e.rig]:
            first[e.rig] = key
    return sorted(first, key=lambda r: first[r])


def locate(entries: Iterable[ResidualEntry], floor_note: str = "") -> Located:
    """Map the residual ``entries`` over every axis (see :class:`Located`).  Entries with no degree
    of freedom are dropped; ``ValueError`` names an entry whose chi2 is not a finite number >= 0."""
    kept = []
    for e in entries:
        if not (math.isfinite(e.chi2) and e.chi2 >= 0):
            raise ValueError(f"residual entry of record {e.record} ({e.rig}, {e.channel}, {e.view}, harmonic "
                             f"{e.harmonic}): chi2 must be finite and >= 0, got {e.chi2!r}")
        if e.dof > 0:
            kept.append(e)

    def axis(name: str, key: Callable[[ResidualEntry], Hashable], order: Callable[[Any], Any]) -> list[dict[str, Any]]:
        cells = _cells(kept, key)
        return [_cell(name, k, c, d) for k, (c, d) in sorted(cells.items(), key=lambda kv: order(kv[0]))]

    rig_order = {r: i for i, r in enumerate(_rigs_in_order(kept))}
    summary = {
        "channels": axis("label", _view_label, _view_key),
        "harmonics": axis("label", lambda e: e.harmonic, _harmonic_key),
        "frequencies_Hz": axis("value", lambda e: _rounded(e.frequency_hz), float),
        "amplitudes_pp_A": axis("value", lambda e: _rounded(e.current_pp_a), float),
        "rigs": axis("label", lambda e: e.rig, lambda r: rig_order[r]),
        "time": _time_trend(kept),
    }
    return Located(tuple(kept), floor_note, summary)


def locate_residual(data: Sequence[Any], layout: Any, resid: np.ndarray, sigma_h: np.ndarray, ok: np.ndarray,
                    line_labels: Sequence[tuple[int, str, float]], resid_l: np.ndarray, sigma_l: np.ndarray,
                    model: np.ndarray | None = None) -> tuple[dict[str, Any], Located]:
    """:func:`locate` of a diagnosis's calibrated baseline: its residual (data minus model) per record,
    view and harmonic as entries, the lines' per channel; given the calibrated ``model`` (harmonic
    rows), also force vs flux: each side's force referenced to its own flux's fundamental, so what
    the iron does to the flux's phase drops out and only the force instrument and the force law remain."""
    entries = []
    if model is not None:
        entries += _force_vs_flux(data, layout, resid, sigma_h, ok, model)
    z2 = np.where(ok, (resid / sigma_h) ** 2, np.nan)
    for r, f in enumerate(data):
        for ci, ch in enumerate(CHANNELS):
            for k in range(int(layout.harmonic.max(initial=0)) + 1):
                sel = (layout.record == r) & (layout.channel == ci) & (layout.harmonic == k) & ok
                if sel.any():
                    entries.append(ResidualEntry(r, f.rig, f.frequency_hz, f.current_pp_a, f.start_time_s, ch,
                                                 CHANNEL_VIEWS[ch], str(k), float(np.sum(z2[sel])), int(sel.sum())))
    for j, (r, ch, hz) in enumerate(line_labels):
        if np.isfinite(resid_l[j]) and sigma_l[j] > 0:
            f = data[r]
            entries.append(ResidualEntry(r, f.rig, f.frequency_hz, f.current_pp_a, f.start_time_s, ch, "alone",
                                         f"line {hz:g} Hz", float((resid_l[j] / sigma_l[j]) ** 2), 1))
    located = locate(entries)
    return located.to_json(), located


def _force_vs_flux(data, layout, resid: np.ndarray, sigma_h: np.ndarray, ok: np.ndarray, model: np.ndarray
                   ) -> list[ResidualEntry]:
    out = []
    flux, force = CHANNELS.index("flux_Wb"), CHANNELS.index("force_N")
    measured = model + resid
    for r, f in enumerate(data):
        rows = {}
        for ci in (flux, force):
            sel = (layout.record == r) & (layout.channel == ci)
            rows[ci] = sel
        if not (rows[flux].any() and rows[force].any()):
            continue
        turned = []
        for vec in (measured, model):
            h = {ci: _complex(vec, layout, rows[ci]) for ci in (flux, force)}
            k = np.arange(h[force].size)
            turned.append(h[force] * np.exp(-1j * k * np.angle(h[flux][1])))
        diff = turned[0] - turned[1]
        for k in range(diff.size):
            sel = rows[force] & (layout.harmonic == k) & ok
            if not sel.any() or not np.isfinite(diff[k]):
                continue
            parts = layout.part[sel]
            z2 = sum(((diff[k].imag if p else diff[k].real) / s) ** 2 for p, s in zip(parts, sigma_h[sel]))
            out.append(ResidualEntry(r, f.rig, f.frequency_hz, f.current_pp_a, f.start_time_s, "force_N",
                                     "force vs flux", str(k), float(z2), int(sel.sum())))
    return out


def _complex(vec: np.ndarray, layout, sel: np.ndarray) -> np.ndarray:
    """One record's complex harmonics of one channel from the vector's rows ``sel``."""
    h = np.zeros(int(layout.harmonic.max(initial=0)) + 1, complex)
    idx = np.flatnonzero(sel)
    np.add.at(h, layout.harmonic[idx], np.where(layout.part[idx] == 0, vec[idx], 1j * vec[idx]))
    return h