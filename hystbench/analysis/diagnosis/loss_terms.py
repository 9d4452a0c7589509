"""The library of loss terms the loss-table diagnosis selects from: each a physically meaningful form
of energy per cycle and volume, with its parameters in physical units.

Why a library: the catalogue names one rate dependence (``lamination_eddy_currents``); real ferrites
show others.  What no catalogue name explains is still modelled, with a generic form, and reported as
"not in the catalogue: <form> with <parameters>" (docs/design.md, "Diagnosis").  The forms:

* ``power``: k f^gamma B^delta S_(1+gamma) -- a rate term whose power grows as |dB/dt|^(1+gamma), carried
  to any waveform by its shape factor (:mod:`.loss_shapes`: Bertotti's separation, the iGSE).  Fixed
  exponents give the classical eddy term and Bertotti's excess term (both catalogue effects:
  ``lamination_eddy_currents``, ``excess_loss``); free exponents give the
  Steinmetz/iGSE term (a power law in f, B and dB/dt at once).
* ``series`` (``rate_series``): the dynamic field as a series in the rate, H = a_1(B) dB/dt +
  a_2(B) dB/dt |dB/dt|, each a_n a power of B: k_1 f B^delta_1 S_2 + k_2 f^2 B^delta_2 S_3.  Its orders in
  f are fixed, so it extrapolates from a calibration window where a free exponent bends to fit it.
* ``relaxation`` (``flat_segment_relaxation``): the i2GSE's magnetic relaxation (J. Muehlethaler, J. Biela, J. W. Kolar, A. Ecklebe,
  IEEE Trans. Power Electron. 27(2), 2012): after a ramp, when B stops (a flat segment of a trapezoid),
  the material keeps dissipating; per transition an energy k_r (|dB/dt| / R0)^alpha_r (dB_pp / 2 B0)^beta_r
  (1 - exp(-t_flat / tau)), R0 = 1 T/us, B0 = 0.1 T, summed over the flat segments of a period.
  MagNet's flat segments are the bridge's zero-voltage intervals (duty_2, duty_4; B truly flat when
  duty_1 == duty_3, otherwise slowly drifting), each after the ramp before it.  A sine or a triangle has
  none: the term is zero there, so it can be fitted only where flat segments were calibrated on.
* ``falling`` (``falling_rate_dependence``): k_f (f/100 kHz)^-gamma (B/0.1 T)^delta, a loss per cycle that
  falls with frequency, which no sum of the rate terms above can do (each adds loss as f grows).  Real
  ferrites show it below a few hundred kHz (N87's sines: gamma 1.6, delta 1.9-2.0 from either split): the
  high-frequency side of a relaxation peak below the band (a Debye's falls as 1/f, with B^2), or a loop
  that the rate shrinks.  Shape-independent (a sine's and a triangle's alike at the same f and B_pk).
* ``temperature``: the whole loop's energy scaled by exp(c1 (T - T0) + c2 (T - T0)^2), T0 = 25 degC --
  the usual Steinmetz temperature polynomial in log form; only where the rows carry a temperature that
  varies.

Each term adds a log-energy ``part`` (the energies add; the temperature factor multiplies all).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np
from scipy.special import digamma

from ...formats.flux_shapes import segment_steps
from .loss_shapes import sine_integral

__all__ = ["Term", "Rows", "TERMS", "STEINMETZ", "SERIES", "RELAXATION", "TEMPERATURE", "TIERS", "LIBRARY", "B0_T", "RATE0_T_PER_S",
           "T0_C", "FREE_BOUNDS", "FALLING", "n_params", "term_part", "term_gradient", "term_start", "term_bounds", "natural", "inert", "form"]

B0_T = 0.1  # the reference flux density
RATE0_T_PER_S = 1e6  # the relaxation's reference ramp rate, 1 T/us
T0_C = 25.0  # the temperature term's reference
#: (gamma, delta) lower and upper bounds of the free power term (alpha = 1 + gamma in P); a fit on a
#: bound is flagged.
FREE_BOUNDS = ((0.1, 1.0), (3.0, 4.0))
RELAX_BOUNDS = ((0.0, 0.0, math.log(1e-9)), (3.0, 4.0, math.log(1e-3)))  # alpha_r, beta_r, ln tau_s


@dataclass(frozen=True)
class Term:
    """One loss term: ``kind`` power (k f^f_exp B^b_exp S, exponents free when ``free``), relaxation
    or temperature; ``coefficient`` names its scale with its unit."""

    name: str
    in_catalogue: bool
    description: str
    f_exp: float
    b_exp: float
    coefficient: str
    free: bool = False
    kind: str = "power"


@dataclass(frozen=True)
class Rows:
    """The operating points a model is evaluated at: f (Hz), peak B (T), MagNet duties (rows, 4) or
    None (all sines), temperature (degC) or None.  What the terms need of them is computed once (a
    fit evaluates the model a thousand times)."""

    f: np.ndarray
    b: np.ndarray
    duty: np.ndarray | None = None
    temperature_c: np.ndarray | None = None
    #: sampled B(t) / B_pk over one period (rows, samples), for measured waveforms instead of ``duty``
    waveform: np.ndarray | None = None

    def take(self, m: np.ndarray) -> "Rows":
        return Rows(self.f[m], self.b[m], None if self.duty is None else self.duty[m],
                    None if self.temperature_c is None else self.temperature_c[m],
                    None if self.waveform is None else self.waveform[m])

    @cached_property
    def ln_f(self) -> np.ndarray:
        return np.log(self.f)

    @cached_property
    def ln_b(self) -> np.ndarray:
        return np.log(self.b)

    @cached_property
    def sine(self) -> np.ndarray:
        return np.ones(self.f.shape, bool) if self.duty is None else np.all(self.duty == -1.0, axis=1)

    @cached_property
    def segments(self) -> tuple[np.ndarray, np.ndarray]:
        """ln d_i and ln |delta b_i| of the four segments (-inf for a segment of no time or no step)."""
        d = np.where(self.sine[:, None], 0.25, self.duty)
        step = np.abs(segment_steps(d))
        live = (d > 0) & (step > 0)
        with np.errstate(divide="ignore"):
            return np.where(live, np.log(d), 0.0), np.where(live, np.log(step), -np.inf)

    @cached_property
    def _fixed_shape_factors(self) -> dict[float, np.ndarray]:
        return {}

    def ln_shape_factor_of_order(self, p: float) -> np.ndarray:
        """:meth:`ln_shape_factor` for a fixed exponent, computed once per rows (a fit evaluates it
        thousands of times; a free exponent's changes each time and is not kept)."""
        cache = self._fixed_shape_factors
        if p not in cache:
            cache[p] = self.ln_shape_factor(p)
        return cache[p]

    def ln_shape_factor(self, p: float) -> np.ndarray:
        """ln S_p (:func:`.loss_shapes.shape_factor`, in log form; 0 for a sine)."""
        if self.waveform is not None:  # the same integral on the samples: mean of |db/dphi|^p
            slope = np.diff(self.waveform, axis=1, append=self.waveform[:, :1]) * self.waveform.shape[1]
            return np.log(np.mean(np.abs(slope) ** p, axis=1) / sine_integral(p))
        if self.duty is None:
            return np.zeros_like(self.f)
        ln_d, ln_s = self.segments
        out = np.logaddexp.reduce((1.0 - p) * ln_d + p * ln_s, axis=1) - math.log(sine_integral(p))
        return np.where(self.sine, 0.0, out)

    def ln_shape_factor_slope(self, p: float) -> np.ndarray:
        """d ln S_p / dp (the free term's shape factor moves with its exponent; its Jacobian needs it)."""
        if self.waveform is not None:
            slope = np.abs(np.diff(self.waveform, axis=1, append=self.waveform[:, :1]) * self.waveform.shape[1])
            with np.errstate(divide="ignore"):
                ln_s = np.where(slope > 0, np.log(np.where(slope > 0, slope, 1.0)), 0.0)
            weight = slope**p
            return np.sum(weight * ln_s, axis=1) / np.sum(weight, axis=1) - _ln_sine_integral_slope(p)
        if self.duty is None:
            return np.zeros_like(self.f)
        ln_d, ln_s = self.segments
        live = np.isfinite(ln_s)
        e = np.where(live, (1.0 - p) * ln_d + p * np.where(live, ln_s, 0.0), -np.inf)
        w = np.exp(e - np.max(e, axis=1, keepdims=True))  # each segment's share of the integral
        out = np.sum(w * np.where(live, ln_s - ln_d, 0.0), axis=1) / np.sum(w, axis=1) - _ln_sine_integral_slope(p)
        return np.where(self.sine, 0.0, out)

    @cached_property
    def flats(self) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
        """Per flat segment (duty_2 after the rise, duty_4 after the fall): rows that have it, ln of
        the ramp's |dB/dt| / R0 before it, and its duration (s)."""
        if self.duty is None:
            return []
        d = np.where(self.sine[:, None], 0.25, self.duty)
        step = segment_steps(d) * self.b[:, None]
        out = []
        for ramp, flat in ((0, 1), (2, 3)):
            live = ~self.sine & (d[:, flat] > 0)
            rate = np.abs(step[:, ramp]) * self.f / d[:, ramp] / RATE0_T_PER_S
            out.append((live, np.log(np.where(live, rate, 1.0)), d[:, flat] / self.f))
        return out


TERMS = {
    "lamination_eddy_currents": Term(
        "lamination_eddy_currents", True,
        "classical eddy-current loss k_c f B^2 (Bertotti); in a ferrite the bulk-eddy/relaxation analogue",
        1.0, 2.0, "k_c_J_s_per_m3_T2"),
    "excess_loss": Term(
        "excess_loss", True, "excess (domain-wall) loss (Bertotti) k_e f^0.5 B^1.5, the catalogue's excess_loss "
        "(its coefficient k = k_e / 8.763, the loss per cycle of its field k sqrt(|dB/dt|) under a sine)",
        0.5, 1.5, "k_e_J_per_m3_Hz0.5_T1.5"),
}
STEINMETZ = Term("steinmetz_rate_dependence", False,
                 "a rate dependence k_s f^gamma B^delta with free exponents (Steinmetz alpha = 1 + gamma, "
                 "the iGSE on other waveforms), not in the catalogue", 0.5, 2.5, "k_s_J_per_m3_at_100kHz_0.1T",
                 free=True)
RELAXATION = Term("flat_segment_relaxation", False,
                  "first-order magnetic relaxation after each ramp into a flat segment (i2GSE) "
                  "k_r (|dB/dt|/1 T/us)^alpha_r (dB_pp/0.2 T)^beta_r (1 - exp(-t_flat/tau)), not in the catalogue "
                  "(the catalogue's magnetic_relaxation is a linear Debye after-effect, another form)",
                  0.0, 0.0, "k_r_J_per_m3_per_transition", kind="relaxation")
SERIES = Term("rate_series", False,
              "a dynamic field in powers of dB/dt, H = a_1(B) dB/dt + a_2(B) dB/dt |dB/dt| (Taylor in the rate): "
              "k_1 (f/100 kHz) (B/0.1 T)^delta_1 S_2 + k_2 (f/100 kHz)^2 (B/0.1 T)^delta_2 S_3, not in the catalogue",
              1.0, 2.0, "k_1_J_per_m3_at_100kHz_0.1T", kind="series")
FALLING = Term("falling_rate_dependence", False,
               "a loss per cycle falling with frequency, k_f (f/100 kHz)^-gamma (B/0.1 T)^delta (the high-frequency side "
               "of a relaxation peak below the band, or a loop the rate shrinks), not in the catalogue", 0.0, 2.0,
               "k_f_J_per_m3_at_100kHz_0.1T", kind="falling")
TEMPERATURE = Term("temperature_dependence", False,
                   "the loop's energy scaled by exp(c1 (T - 25 degC) + c2 (T - 25 degC)^2), not in the catalogue",
                   0.0, 0.0, "c1_per_K", kind="temperature")
#: Every candidate, in three tiers: the named physics of fixed form first (Bertotti's terms: a term
#: we can name from physics belongs in the model), then the generic forms whose orders in the rate are
#: fixed (the series, the relaxation, the temperature factor), then a free exponent in f for what they
#: leave.  Why the free exponent comes last: it fits a calibration window more closely than it
#: extrapolates from it.  Calibrated at 50-190 kHz and held out to 500 kHz, it went to alpha 3.8 on N87
#: and predicted 0.155 log10, where the series predicts 0.038 (docs/diagnosis.md, "The rate series").
#: Where a calibration window cannot tell the two apart, the order decides; across the band a free
#: exponent that is the truth is decisive on top of the series and drops it (``_drop_redundant``).
TIERS = (tuple(TERMS.values()), (SERIES, RELAXATION, TEMPERATURE, FALLING), (STEINMETZ,))
LIBRARY = tuple(t for tier in TIERS for t in tier)
F0_HZ = 1e5  # the free term's reference frequency (its k is the energy there at B0, a sine)
ENERGY_FLOOR_J_PER_M3 = 1e-9  # the least a term's energy per cycle may be at its reference point


def n_params(t: Term) -> int:
    return {"power": 3 if t.free else 1, "series": 4, "relaxation": 4, "temperature": 2, "falling": 3}[t.kind]


def _relax_energy(x: np.ndarray, rows: Rows) -> np.ndarray:
    """The relaxation's sum over a period's flat segments, without k_r (0 where there is none)."""
    out = np.zeros_like(rows.f)
    alpha, beta, tau = x[0], x[1], math.exp(x[2])
    for live, ln_rate, t_flat in rows.flats:
        out += np.where(live, np.exp(alpha * ln_rate) * -np.expm1(-t_flat / tau), 0.0)
    return out * np.exp(beta * (rows.ln_b - math.log(B0_T)))  # dB_pp / 0.2 T = B_pk / 0.1 T


def term_part(t: Term, x: np.ndarray, rows: Rows) -> np.ndarray:
    """ln of the term's energy per cycle at every row (-inf where it is zero); for ``temperature`` the
    ln of its factor."""
    if t.kind == "temperature":
        if rows.temperature_c is None:
            return np.zeros_like(rows.f)
        dt = rows.temperature_c - T0_C
        return x[0] * dt + x[1] * dt**2
    if t.kind == "series":
        lf, lb = rows.ln_f - math.log(F0_HZ), rows.ln_b - math.log(B0_T)
        return np.logaddexp(x[0] + lf + x[1] * lb + rows.ln_shape_factor_of_order(2.0),
                            x[2] + 2.0 * lf + x[3] * lb + rows.ln_shape_factor_of_order(3.0))
    if t.kind == "falling":
        return x[0] - x[1] * (rows.ln_f - math.log(F0_HZ)) + x[2] * (rows.ln_b - math.log(B0_T))
    if t.kind == "relaxation":
        e = _relax_energy(x[1:], rows)
        with np.errstate(divide="ignore"):
            return x[0] + np.log(e)
    if t.free:
        g, d = x[1], x[2]
        return (x[0] + g * (rows.ln_f - math.log(F0_HZ)) + d * (rows.ln_b - math.log(B0_T))
                + rows.ln_shape_factor(1.0 + g))
    return x[0] + t.f_exp * rows.ln_f + t.b_exp * rows.ln_b + rows.ln_shape_factor_of_order(1.0 + t.f_exp)


def term_gradient(t: Term, x: np.ndarray, rows: Rows) -> np.ndarray:
    """d :func:`term_part` / dx at every row, (rows, n_params): the fits' Jacobian in closed form (a
    finite-difference one took half of a loss diagnosis's time).  Where a term is zero (a relaxation
    without a flat segment) its gradient is 0: its weight in the sum of energies is."""
    n = rows.f.size
    if t.kind == "temperature":
        if rows.temperature_c is None:
            return np.zeros((n, 2))
        dt = rows.temperature_c - T0_C
        return np.column_stack([dt, dt**2])
    lf, lb = rows.ln_f - math.log(F0_HZ), rows.ln_b - math.log(B0_T)
    if t.kind == "series":
        a = x[0] + lf + x[1] * lb + rows.ln_shape_factor_of_order(2.0)
        b = x[2] + 2.0 * lf + x[3] * lb + rows.ln_shape_factor_of_order(3.0)
        share = np.exp(a - np.logaddexp(a, b))
        return np.column_stack([share, share * lb, 1.0 - share, (1.0 - share) * lb])
    if t.kind == "falling":
        return np.column_stack([np.ones(n), -lf, lb])
    if t.kind == "relaxation":
        alpha, tau = x[1], math.exp(x[3])
        total, d_alpha, d_tau = np.zeros(n), np.zeros(n), np.zeros(n)
        for live, ln_rate, t_flat in rows.flats:
            rate = np.where(live, np.exp(alpha * ln_rate), 0.0)
            u = t_flat / tau
            total += rate * -np.expm1(-u)
            d_alpha += rate * -np.expm1(-u) * ln_rate
            d_tau -= rate * u * np.exp(-u)  # d(1 - e^-u) / d ln tau, u = t / tau
        some = total > 0
        safe = np.where(some, total, 1.0)
        return np.column_stack([np.where(some, 1.0, 0.0), np.where(some, d_alpha / safe, 0.0),
                                np.where(some, lb, 0.0), np.where(some, d_tau / safe, 0.0)])
    if t.free:
        return np.column_stack([np.ones(n), lf + rows.ln_shape_factor_slope(1.0 + x[1]), lb])
    return np.ones((n, 1))


def _ln_sine_integral_slope(p: float) -> float:
    """d ln sine_integral(p) / dp."""
    return math.log(2.0 * math.pi) + 0.5 * float(digamma((p + 1.0) / 2.0) - digamma(p / 2.0 + 1.0))


def term_start(t: Term, y: np.ndarray, rows: Rows, share: float, g0: float) -> list[float]:
    """A start at ``share`` of the median energy (``g0``: the free term's start in gamma, or the
    relaxation's ln tau)."""
    if t.kind == "temperature":
        return [0.0, 0.0]
    if t.kind == "relaxation":
        return [float(np.median(y)) + math.log(share), 1.0, 2.5, g0]
    if t.kind == "falling":
        return [float(np.median(y)) + math.log(share), g0, 2.5]
    if t.kind == "series":
        return [float(np.median(y)) + math.log(share * g0), 2.0, float(np.median(y)) + math.log(share * (1 - g0)), 2.0]
    if t.free:
        base = y - g0 * np.log(rows.f / F0_HZ) - t.b_exp * np.log(rows.b / B0_T)
        return [float(np.median(base)) + math.log(share), g0, t.b_exp]
    return [float(np.median(y - t.f_exp * np.log(rows.f) - t.b_exp * np.log(rows.b))) + math.log(share)]


def term_starts(t: Term) -> tuple[float, ...]:
    """The second start coordinate tried per term (free gamma, relaxation ln tau)."""
    if t.free:
        return (0.5, 1.5)
    if t.kind == "relaxation":
        return (math.log(1e-7), math.log(1e-5))
    if t.kind == "series":
        return (0.9, 0.3)  # the first order's share of the start
    if t.kind == "falling":
        return (0.5, 1.0)  # gamma
    return (0.0,)


def term_bounds(t: Term) -> tuple[list[float], list[float]]:
    """Each energy term's ln scale is bounded below at ENERGY_FLOOR at its reference point: a term
    fitted to nothing stops there instead of walking its log towards -inf (speed; 1e-9 J/m^3 is
    eight decades below any measured loss per cycle)."""
    floor = math.log(ENERGY_FLOOR_J_PER_M3)
    if t.kind == "temperature":
        return [-0.2, -0.01], [0.2, 0.01]
    if t.kind == "relaxation":
        return [floor, *RELAX_BOUNDS[0]], [np.inf, *RELAX_BOUNDS[1]]
    if t.kind == "falling":  # gamma 0.1-2 (a Debye's tail falls as 1/f), delta as the free term's
        return [floor, 0.1, FREE_BOUNDS[0][1]], [np.inf, 2.0, FREE_BOUNDS[1][1]]
    if t.kind == "series":
        return [floor, FREE_BOUNDS[0][1], floor, FREE_BOUNDS[0][1]], [np.inf, FREE_BOUNDS[1][1], np.inf, FREE_BOUNDS[1][1]]
    if t.free:
        return [floor, *FREE_BOUNDS[0]], [np.inf, *FREE_BOUNDS[1]]
    return [floor - t.f_exp * math.log(F0_HZ) - t.b_exp * math.log(B0_T)], [np.inf]  # k in SI: energy k f^g B^d


def inert(t: Term, rows: Rows) -> str | None:
    """Why ``t`` cannot be fitted on ``rows`` (it is zero or constant on all of them), or None."""
    if t.kind == "relaxation" and (rows.duty is None or not np.any((rows.duty[:, 0] != -1)
                                                                   & ((rows.duty[:, 1] > 0) | (rows.duty[:, 3] > 0)))):
        return "no calibration row has a flat segment (only sines and triangles): relaxation is not identifiable there"
    if t.kind == "temperature" and (rows.temperature_c is None or np.ptp(rows.temperature_c) == 0):
        return "the calibration rows have one temperature"
    return None


def natural(t: Term, x: np.ndarray, se: np.ndarray) -> dict[str, tuple[float, float]]:
    """The term's parameters (value, std) in physical units, by the delta method from the fit's (NaN:
    not determined)."""
    if t.kind == "temperature":
        return {"c1_per_K": (x[0], se[0]), "c2_per_K2": (x[1], se[1])}
    k = math.exp(x[0])
    p = {t.coefficient: (k, k * se[0])}
    if t.kind == "series":
        k2 = math.exp(x[2])
        p.update({"delta_1": (x[1], se[1]), "k_2_J_per_m3_at_100kHz_0.1T": (k2, k2 * se[2]), "delta_2": (x[3], se[3])})
        for key, k_order, k_std in (("delta_1", k, se[0]), ("delta_2", k2, se[2])):
            if k_order < 1e-6 * (k + k2) or not math.isfinite(k_std):  # fitted to nothing: no exponent
                del p[key]
        return p
    if t.kind == "falling":
        p.update({"gamma": (x[1], se[1]), "delta": (x[2], se[2])})
        return p
    if t.kind == "relaxation":
        tau = math.exp(x[3])
        p.update({"alpha_r": (x[1], se[1]), "beta_r": (x[2], se[2]), "tau_s": (tau, tau * se[3])})
        return p
    if t.name == "lamination_eddy_currents":  # W_cl = pi^2 sigma d^2 f B^2 / 6
        p["sigma_d2_S_m"] = (6.0 * k / math.pi**2, 6.0 * k * se[0] / math.pi**2)
    if t.name == "excess_loss":  # the catalogue's field k sqrt|dB/dt| takes k B^1.5 f^0.5 sine_integral(1.5) a cycle
        c = sine_integral(1.5)
        p["coefficient_a_per_m_per_sqrt_t_per_s"] = (k / c, k * se[0] / c)
    if t.free:
        p["alpha"] = (1.0 + x[1], se[1])
        p["delta"] = (x[2], se[2])
    return p


def form(t: Term, p: dict[str, tuple[float, float]]) -> str:
    """'not in the catalogue: <form> with <parameters>' for a generic term, its name for a catalogue one."""
    if t.in_catalogue:
        return t.name
    pm = ", ".join(f"{k} = {v:.4g} +- {s:.2g}" if math.isfinite(s) else f"{k} = {v:.4g} (not determined by the rows)"
                   for k, (v, s) in p.items())
    shapes = {"excess_loss": "k_e f^0.5 B^1.5 S_1.5",
              "steinmetz_rate_dependence": "k_s (f/100 kHz)^gamma (B/0.1 T)^delta S_(1+gamma) (iGSE), alpha = 1 + gamma",
              "rate_series": "k_1 (f/100 kHz) (B/0.1 T)^delta_1 S_2 + k_2 (f/100 kHz)^2 (B/0.1 T)^delta_2 S_3 (a dynamic "
                             "field a_1(B) dB/dt + a_2(B) dB/dt |dB/dt|)",
              "flat_segment_relaxation": "k_r (|dB/dt|/1 T/us)^alpha_r (B_pk/0.1 T)^beta_r (1 - exp(-t_flat/tau)) "
                                     "per ramp into a flat segment (i2GSE)",
              "temperature_dependence": "W exp(c1 (T - 25 degC) + c2 (T - 25 degC)^2)",
              "falling_rate_dependence": "k_f (f/100 kHz)^-gamma (B/0.1 T)^delta, a loss per cycle falling with "
                                         "frequency (the high-frequency side of a relaxation peak below the band, or a "
                                         "loop the rate shrinks)"}
    return f"{t.name} (not in the catalogue: {shapes.get(t.name, t.description)} with {pm})"
