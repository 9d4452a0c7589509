"""Fit the Preisach material model to the real measured loops, and measure how well it fits.

Loops are driven the way they were measured: from the demagnetised state the field jumps to +Hm
(the virgin curve ends on the loop tip), then follows the measured H samples; the error is the
model's B at the measured H minus the measured B, so saturation tails (where B hardly moves) weigh
only as much as they matter.  One parameter set must fit all loops of a material.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Sequence

import numpy as np
from scipy.optimize import least_squares

from ..errors import ConfigError
from .hysteresis import PreisachHysteresis, PreisachParams, mu_0
from .hysteresis_kernel import field_along

__all__ = [
    "MeasuredLoop", "load_loops", "model_loop", "loop_error", "loop_area", "baseline_error", "fit_material",
    "material_toml", "first_harmonic", "b_lag_behind_h_deg", "operating_point_lag_deg",
    "MATERIAL_DATA",
]

#: where the measured loops ship: copied, with their licences, from third-party measurements
#: (measured/README.md names the sources)
MEASURED_DIR = Path(__file__).resolve().parent / "measured"

#: material -> (data file under MEASURED_DIR, how its loops are laid out)
MATERIAL_DATA = {
    "M330-50A": ("epstein_static_loops/M330_50A_envelope.csv", "envelope"),
    "M130-27S": ("quasistatic_loops/M130_27s_3mixed_loops.csv", "pairs"),
}


@dataclass(frozen=True)
class MeasuredLoop:
    """One measured symmetric loop, in measuring order: from (+Hm, +Bm) down to -Hm and back."""

    label: str
    h_a_per_m: np.ndarray
    b_t: np.ndarray
    turn: int  # index of the sample at -Hm (end of the descending branch)

    @property
    def h_max(self) -> float:
        return float(self.h_a_per_m[0])

    @property
    def b_max(self) -> float:
        return float(0.5 * (self.b_t[0] - self.b_t[self.turn]))


def load_loops(material: str, data_dir: Path | None = None) -> list[MeasuredLoop]:
    """The real loops of ``material`` (a key of MATERIAL_DATA)."""
    if material not in MATERIAL_DATA:
        raise ConfigError(f"no measured loops for material {material!r}; known: {', '.join(MATERIAL_DATA)}")
    rel, layout = MATERIAL_DATA[material]
    path = (data_dir or MEASURED_DIR) / rel
    try:
        data = np.loadtxt(path, delimiter=",", skiprows=1)
    except OSError as err:
        raise ConfigError(f"{path}: cannot read measured loops: {err}") from err
    if layout == "envelope":  # H ascending; falling branch walked from +Hm down, then rising back up
        h, b_up, b_down = data.T
        hh = np.concatenate([h[::-1], h[1:]])
        bb = np.concatenate([b_down[::-1], b_up[1:]])
        return [MeasuredLoop(f"{material} major loop", hh, bb, h.size - 1)]
    loops = []
    for k in range(data.shape[1] // 2):
        h, b = data[:, 2 * k], data[:, 2 * k + 1]
        loops.append(MeasuredLoop(f"{material} Hm={h[0]:g} A/m", h, b, int(np.argmin(h))))
    return loops


def model_loop(model: PreisachHysteresis, loop: MeasuredLoop) -> np.ndarray:
    """Model B (T) at every measured H of ``loop``, starting demagnetised."""
    b, _ = model.flux_density(np.concatenate([[loop.h_max], loop.h_a_per_m]), model.initial_state())
    return b[1:]


def loop_error(model: PreisachHysteresis, loop: MeasuredLoop) -> dict[str, float]:
    """RMS and max |B_model - B_measured| at the measured H, in T and in % of the loop's Bm, and
    the ratio of the loop areas (energy lost per cycle), model over measured."""
    b = model_loop(model, loop)
    e = b - loop.b_t
    rms, mx = float(np.sqrt(np.mean(e * e))), float(np.max(np.abs(e)))
    bm = loop.b_max
    area = loop_area(loop.h_a_per_m, b) / loop_area(loop.h_a_per_m, loop.b_t)
    return {"b_max_t": bm, "rms_t": rms, "max_t": mx, "rms_pct": 100 * rms / bm, "max_pct": 100 * mx / bm,
            "area_ratio": area}


def loop_area(h: np.ndarray, b: np.ndarray) -> float:
    """Energy dissipated per cycle, the closed integral of H dB (J/m^3), by the trapezoid rule
    over the samples in order (closed by the segment from the last sample back to the first)."""
    hh, bb = np.append(h, h[0]), np.append(b, b[0])
    return float(np.sum(0.5 * (hh[1:] + hh[:-1]) * np.diff(bb)))


def baseline_error(loop: MeasuredLoop) -> dict[str, float]:
    """The same metrics for the best single-valued curve (zero loop area): the mean of the two
    branches at each H, so each branch misses it by half the loop's width in B."""
    hd, bd = loop.h_a_per_m[: loop.turn + 1][::-1], loop.b_t[: loop.turn + 1][::-1]
    ha, ba = loop.h_a_per_m[loop.turn:], loop.b_t[loop.turn:]
    mid = 0.5 * (np.interp(loop.h_a_per_m, hd, bd) + np.interp(loop.h_a_per_m, ha, ba))
    e = mid - loop.b_t
    rms, mx = float(np.sqrt(np.mean(e * e))), float(np.max(np.abs(e)))
    return {"b_max_t": loop.b_max, "rms_t": rms, "max_t": mx,
            "rms_pct": 100 * rms / loop.b_max, "max_pct": 100 * mx / loop.b_max}


# ---- fitting -----------------------------------------------------------------------------------
def _initial(loops: Sequence[MeasuredLoop], kinds: Sequence[str], h_max: float) -> PreisachParams:
    """A start from the largest loop: coercive field Hc, remanence Br, tip (Hm, Bm)."""
    big = max(loops, key=lambda lp: lp.b_max)
    hd, bd = big.h_a_per_m[: big.turn + 1][::-1], big.b_t[: big.turn + 1][::-1]
    hc = abs(float(np.interp(0.0, bd, hd)))
    br = float(np.interp(0.0, hd, bd))
    shapes = [(1.0, hc, 0.15 * hc), (0.5, hc, 2.0 * hc), (1.0, 1.4 * hc, 0.35 * hc)]
    comps = tuple((k, *shapes[i % 3]) for i, k in enumerate(kinds))
    j_rev = max(big.b_max - br - mu_0 * big.h_max, 0.05)
    rev = ((0.3 * j_rev, 8 * hc), (0.7 * j_rev, max(big.h_max / 4, 30 * hc)))
    return PreisachParams(j_irr_t=br, components=comps, reversible=rev, h_max_a_per_m=h_max,
                          h_scale_a_per_m=hc / 4)


def _pack(p: PreisachParams) -> np.ndarray:
    c = p.components
    v = [p.j_irr_t] + [w / c[0][1] for _, w, _, _ in c[1:]] + [x for _, _, m, s in c for x in (m, s)]
    v += [x for t in p.reversible for x in t]
    return np.log(np.asarray(v, float))


def _unpack(q: np.ndarray, like: PreisachParams) -> PreisachParams:
    v = np.exp(q).tolist()
    nc = len(like.components)
    ws = [1.0] + v[1:nc]
    tot = sum(ws)
    ms = v[nc:3 * nc]
    comps = tuple((k, ws[i] / tot, ms[2 * i], ms[2 * i + 1]) for i, (k, *_) in enumerate(like.components))
    rv = v[3 * nc:]
    rev = tuple((rv[2 * i], rv[2 * i + 1]) for i in range(len(rv) // 2))
    return replace(like, j_irr_t=v[0], components=comps, reversible=rev)


def fit_material(loops: Sequence[MeasuredLoop], *, kinds: Sequence[str] = ("gauss", "lorentz", "lorentz"),
                 h_max_a_per_m: float | None = None, start: PreisachParams | None = None,
                 max_nfev: int = 400, area_weight: float = 1.0) -> PreisachParams:
    """Least-squares fit of one parameter set to every loop.

    Residuals: B error at the measured H in units of the loop's Bm (the error the report states),
    and per loop the relative error of the loop area (energy lost per cycle, what the phase lag of
    the flux depends on), with weight ``area_weight``."""
    h_max = h_max_a_per_m or max(lp.h_max for lp in loops)
    p0 = start or _initial(loops, kinds, h_max)
    trajectories = [np.concatenate([[lp.h_max], lp.h_a_per_m]) for lp in loops]
    areas = [loop_area(lp.h_a_per_m, lp.b_t) for lp in loops]

    def residual(q):
        model = PreisachHysteresis(_unpack(q, p0))
        out = []
        for lp, h, area in zip(loops, trajectories, areas):
            b, _ = model.flux_density(h, model.initial_state())
            out.append((b[1:] - lp.b_t) / lp.b_max)  # relative: small loops count as much as big ones
            out.append([area_weight * (loop_area(lp.h_a_per_m, b[1:]) / area - 1.0)])
        return np.concatenate(out)

    sol = least_squares(residual, _pack(p0), max_nfev=max_nfev, x_scale=1.0)
    return _unpack(sol.x, p0)


def material_toml(name: str, p: PreisachParams, header: str, errors: dict[str, dict[str, float]]) -> str:
    """The material file for ``p``; ``header`` becomes the leading comment (data, command)."""
    lines = [f"# {ln}".rstrip() for ln in header.strip().splitlines()]
    lines.append("# Fit errors (B at the measured H, model vs measured):")
    for label, e in errors.items():
        lines.append(f"#   {label}: RMS {e['rms_t'] * 1e3:.1f} mT ({e['rms_pct']:.2f} % of Bm = {e['b_max_t']:.3f} T),"
                     f" max {e['max_t'] * 1e3:.1f} mT ({e['max_pct']:.2f} %), loop area x {e['area_ratio']:.3f}")
    lines += ["", f'name = "{name}"', "model = \"preisach-factorised\"", "", "[preisach]",
              "# mu(alpha, beta) = j_irr_t f(alpha) f(-beta) / Z; f = sum of weight x shape(centre, width)",
              f"j_irr_t = {p.j_irr_t:.10g}", f"h_max_a_per_m = {p.h_max_a_per_m:.10g}",
              f"h_scale_a_per_m = {p.h_scale_a_per_m:.10g}  # grid warp: H = h_scale sinh(x)"]
    for kind, w, c, s in p.components:
        lines += ["", "[[preisach.components]]", f'kind = "{kind}"', f"weight = {w:.10g}",
                  f"centre_a_per_m = {c:.10g}", f"width_a_per_m = {s:.10g}"]
    lines += ["", "[reversible]", "# B_rev(H) = mu0 H + sum j_t 2/pi atan(H / h_a_per_m)"]
    for j, h in p.reversible:
        lines += ["", "[[reversible.terms]]", f"j_t = {j:.10g}", f"h_a_per_m = {h:.10g}"]
    return "\n".join(lines) + "\n"


# ---- phase lag at an operating point ------------------------------------------------------------
def first_harmonic(x: np.ndarray) -> complex:
    """Complex amplitude of the first harmonic of ``x`` sampled over exactly one period (explicit
    DFT): x ~ Re(X exp(j 2 pi k / n))."""
    n = x.size
    return complex(2.0 / n * np.sum(x * np.exp(-2j * np.pi * np.arange(n) / n)))


def b_lag_behind_h_deg(b: np.ndarray, h: np.ndarray) -> float:
    """How far B's first harmonic lags H's (degrees) over one period; > 0 for a lossy loop
    (H leads B), the same sign as "flux behind current" in an inductor."""
    return math.degrees(np.angle(first_harmonic(h) / first_harmonic(b)))


def operating_point_lag_deg(model: PreisachHysteresis, b_amp_t: float, b_bias_t: float = 0.0,
                            n_per_cycle: int = 2000, cycles: int = 3) -> float:
    """Lag of B behind H for B = bias + amp sin(wt) in steady state: the bias is reached on the
    virgin curve (as when a magnet is fitted or a DC current switched on), the last cycle is used."""
    ph = 2 * np.pi * np.arange(cycles * n_per_cycle) / n_per_cycle
    b = b_bias_t + b_amp_t * np.sin(ph)
    state = field_along(model, np.array([b_bias_t]), model.initial_state())[1]
    h, _ = field_along(model, b, state)
    return b_lag_behind_h_deg(b[-n_per_cycle:], h[-n_per_cycle:])
