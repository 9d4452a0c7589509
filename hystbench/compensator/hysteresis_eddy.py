"""Our force model: a rate-dependent hysteresis operator -- static Preisach iron plus an eddy term --
in front of the static force law, identified from a sweep's current, flux and force.

Why this structure (what the measurements show, ``docs/compensator.md``): after the paper's Eq. 6
the residual loops are not ellipses and their shape changes with amplitude; the flux-current
loops show why: the current splits into what the airgaps see and what the iron takes,

    i = j + d_iron(j) + eps j + delta + tau dj/dt,        F = k0 + k1 j + k2 j^2,

and the iron's share d_iron is a hysteresis loop whose shape (not only its phase) depends on the
amplitude and offset, while the eddy share tau dj/dt grows with frequency.  ``j`` follows from the
measured flux (the force is quadratic in it), so every recording of a sweep yields j(t) and
d(t) = i - j directly.  d_iron is a Preisach model of the iron's field H against its flux density
B (factorised density: a Gaussian and a Lorentzian switching-field distribution plus two
reversible terms), in the coordinates of the MEC (B = b0 + b_per_a j, d = H l / N1), identified
by least squares on d -- weighted by dF/dj over each recording's force range, so the fit
minimises the force-prediction error the accuracy figure measures.  The operator is the
project's :class:`~hystbench.physics.hysteresis.PreisachHysteresis` (run with B as input); its
parameters come only from the measurements.

``j`` and the law come from :mod:`.calibration`, which puts the iron's mean in-phase share into
the flux-to-current map; ``eps j + delta`` (fitted, small, either sign) gives the Preisach iron
back the slope and level that map took, so its loops keep their physical, rising shape.

Directions: the inverse (feed-forward: force -> j -> i) is explicit; the forward prediction
(i -> j) is a fixed point j = (i - delta - d_iron(j)) / (1 + eps + s tau), solved with the eddy
term exact per harmonic; d_iron changes by at most ~0.2 of a change in j, so it contracts fast (a fit
to an iron not of the Preisach family can be steeper: a pass that contracts less than 0.7x halves the step).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property
from typing import TYPE_CHECKING, Iterable

import numpy as np

from ..config.presets import PREISACH_KINDS
from ..errors import ConfigError
from ..physics.hysteresis import PreisachHysteresis, PreisachParams
from ..physics.hysteresis_kernel import field_along
from .errors import CompensatorError
from .periodic import derivative, harmonics
from .seen_current import SeenCurrentModel
from .static import StaticLaw

if TYPE_CHECKING:
    from ..physics.mec import ECoreMEC

__all__ = ["IronScaling", "HysteresisEddyModel", "FULL_TABLES", "FIT_TABLES", "PERIODS_TO_STEADY"]

#: Inverse-branch table sizes of the Preisach operator: the final model, and the fit's trial models
#: (4x coarser; their H differs by ~0.3 % of a loop, far below what the fit resolves).
FULL_TABLES = dict(fine_nodes=4001, table_rows=1001, table_cols=1024)
FIT_TABLES = dict(fine_nodes=1001, table_rows=201, table_cols=256)
#: A periodic B with its global extremes in every period is periodic in H after the first period
#: (the demagnetised start's virgin branch is wiped out by then); the second period is the answer.
PERIODS_TO_STEADY = 2
_H_MAX = 5.0e4  # A/m: numerical edge of the operator's tables, far beyond any loop here
_MAX_ITER, _TOL_A = 80, 1e-10
#: A fixed point stalled below this is accepted (see effective_current): 1e-5 A, or 1e-4 of the current's
#: peak-to-peak (a force error of at most ~5e-5 of the range, 0.005 points of accuracy)
_STALL_A, _STALL_REL = 1e-5, 1e-4


@dataclass(frozen=True)
class IronScaling:
    """The MEC's map between the model's currents and the iron (coil-leg flux density and field).

    B = b0_t + b_per_a * j (T; b0 is the magnet's bias), H = d / d_per_h (A/m; d in A)."""

    b0_t: float
    b_per_a: float
    d_per_h: float

    @classmethod
    def from_mec(cls, mec: ECoreMEC) -> "IronScaling":
        """The scaling of the actuator's magnetic circuit at its nominal airgap: the model then
        runs the iron at the flux densities the coil and the magnet really give it."""
        g = mec.geometry
        co = mec.flux_coefficients(g.airgap_m)
        area = g.middle_area_m2
        return cls(co.coil_leg[1] * mec.magnet_mmf_a / area, co.coil_leg[0] * g.coil_turns / area,
                   g.iron_path_length_m / g.coil_turns)

    def to_dict(self) -> dict:
        return {"b0_T": self.b0_t, "b_per_A": self.b_per_a, "d_per_H": self.d_per_h}

    @classmethod
    def from_dict(cls, d: dict) -> "IronScaling":
        return cls(float(d["b0_T"]), float(d["b_per_A"]), float(d["d_per_H"]))


def preisach_params(material: dict, tables: dict) -> PreisachParams:
    """PreisachParams from the model file's ``material`` table at the given table sizes."""
    return PreisachParams(
        j_irr_t=float(material["j_irr_T"]),
        components=tuple((str(k), float(w), float(c), float(s)) for k, w, c, s in material["components"]),
        reversible=tuple((float(j), float(h)) for j, h in material["reversible"]),
        h_max_a_per_m=_H_MAX, h_scale_a_per_m=float(material["h_scale_A_per_m"]), **tables)


@dataclass
class HysteresisEddyModel(SeenCurrentModel):
    """i = j + d_iron(j) + eps j + delta + tau dj/dt, F = law(j): see the module docstring."""

    law: StaticLaw
    scaling: IronScaling
    material: dict  # j_irr_T, components [(kind, weight, centre, width)], reversible [(J, h)], h_scale
    tau_s: float
    report: dict = field(default_factory=dict)
    linear: float = 0.0  # eps (A/A)
    offset_a: float = 0.0  # delta
    kind = "best"
    name = "hysteresis_eddy"

    @cached_property
    def iron(self) -> PreisachHysteresis:
        try:
            return PreisachHysteresis(preisach_params(self.material, FULL_TABLES))
        except (ConfigError, ValueError, KeyError, TypeError) as err:
            raise CompensatorError(f"hysteresis_eddy model: invalid material parameters: {err}") from err

    # --- the operator ------------------------------------------------------------------------------
    def iron_drop(self, j_a: np.ndarray) -> np.ndarray:
        """The iron's static share d_iron (A) over one period of j, in periodic steady state."""
        return iron_drop(self.iron, self.scaling, j_a)

    def current_for(self, j_a: np.ndarray, frequency_hz: float) -> np.ndarray:
        """The coil current that makes the airgaps see ``j_a`` (one period)."""
        j = np.asarray(j_a, float)
        return (1.0 + self.linear) * j + self.offset_a + self.iron_drop(j) + self.tau_s * derivative(j, frequency_hz)

    def effective_current(self, current_a: np.ndarray, frequency_hz: float) -> np.ndarray:
        """j for one period of the coil current (the fixed point of the module docstring)."""
        i = np.asarray(current_a, float)
        lag = 1.0 + self.linear + 2j * np.pi * frequency_hz * self.tau_s * harmonics(i.size)
        j = i.copy()
        steps: list[float] = []
        stall = max(_STALL_A, _STALL_REL * float(np.ptp(i)))
        relax = 1.0  # halved whenever a pass contracts less than 0.7x: a steep fitted iron overshoots and flip-flops
        for _ in range(_MAX_ITER):
            j_new = np.fft.irfft(np.fft.rfft(i - self.offset_a - self.iron_drop(j)) / lag, i.size)
            steps.append(float(np.max(np.abs(j_new - j))))
            if steps[-1] < _TOL_A:
                return j_new
            if len(steps) > 8 and steps[-1] < stall and min(steps[-5:]) >= 0.5 * min(steps[:-5]):
                # a flip-flop of a few uA: the operator's branch tables are piecewise linear, so the map
                # has tiny kinks (and a fit to a foreign iron, small jumps); the midpoint is as good as it gets
                return j + 0.5 * relax * (j_new - j)
            if len(steps) > 1 and steps[-1] > 0.7 * steps[-2]:
                relax = max(0.5 * relax, 1.0 / 64)
            j = j + relax * (j_new - j)
        raise CompensatorError(f"hysteresis_eddy model: the current-to-flux fixed point did not converge "
                               f"(last step {steps[-1]:.3g} A after {_MAX_ITER} passes)")

    def to_dict(self) -> dict:
        return {"kind": self.kind, "name": self.name, "law": self.law.to_dict(), "scaling": self.scaling.to_dict(),
                "material": self.material, "tau_s": self.tau_s, "linear": self.linear, "offset_A": self.offset_a,
                "report": self.report}

    @classmethod
    def from_dict(cls, d: dict) -> "HysteresisEddyModel":
        """The model a file describes, each value checked where the physics needs it (a file's tau of
        -1 s predicted 34 N of error without a word, an h_scale of 0 divided by zero)."""
        m = d["material"]
        material = {"j_irr_T": float(m["j_irr_T"]), "h_scale_A_per_m": float(m["h_scale_A_per_m"]),
                    "components": [[str(k), float(w), float(c), float(s)] for k, w, c, s in m["components"]],
                    "reversible": [[float(j), float(h)] for j, h in m["reversible"]]}
        model = cls(StaticLaw.from_dict(d["law"]), IronScaling.from_dict(d["scaling"]), material,
                    float(d["tau_s"]), dict(d.get("report", {})), float(d.get("linear", 0.0)),
                    float(d.get("offset_A", 0.0)))
        for key, v, low in (("material.j_irr_T", material["j_irr_T"], 0.0), ("material.h_scale_A_per_m",
                                                                              material["h_scale_A_per_m"], 0.0),
                            ("tau_s", model.tau_s, None), ("scaling.b_per_A", model.scaling.b_per_a, 0.0),
                            ("scaling.d_per_H", model.scaling.d_per_h, 0.0)):
            if not (v >= 0 if low is None else v > low):
                raise ValueError(f"{key} must be {'>= 0' if low is None else '> 0'}, got {v!r}")
        if not material["components"]:
            raise ValueError("material.components: none")
        for k, (kind, w, _, width) in enumerate(material["components"]):
            if kind not in PREISACH_KINDS or not (w > 0 and width > 0):
                raise ValueError(f"material.components[{k}]: a {'/'.join(PREISACH_KINDS)} of weight > 0 and width > 0, "
                                 f"got {[kind, w, width]}")
        if not all(h > 0 for _, h in material["reversible"]):
            raise ValueError("material.reversible: every field scale must be > 0")
        return model


def iron_drop(iron: PreisachHysteresis, scaling: IronScaling, j_a: np.ndarray) -> np.ndarray:
    """d_iron over one period of j: the operator run from the demagnetised state for
    PERIODS_TO_STEADY periods, the last one returned."""
    j = np.asarray(j_a, float)
    b = scaling.b0_t + scaling.b_per_a * np.tile(j, PERIODS_TO_STEADY)
    h, _ = field_along(iron, b, iron.initial_state())  # compiled: a fit runs this thousands of times
    out = h[-j.size:] * scaling.d_per_h
    if not np.all(np.isfinite(out)):
        raise CompensatorError("hysteresis_eddy model: the iron operator returned non-finite values")
    return out


def material_dict(j_irr: float, components: Iterable[tuple[str, float, float, float]],
                  reversible: Iterable[tuple[float, float]], h_scale: float) -> dict:
    """The model file's ``material`` table (the inverse of :func:`preisach_params`): an identified
    iron is saved with the model as plain JSON numbers."""
    return {"j_irr_T": float(j_irr), "h_scale_A_per_m": float(h_scale),
            "components": [[str(k), float(w), float(c), float(s)] for k, w, c, s in components],
            "reversible": [[float(j), float(h)] for j, h in reversible]}


def coercive_guess(d_loops: list[np.ndarray], scaling: IronScaling) -> float:
    """A starting coercive field (A/m): the widest loop's half-height in d, as H."""
    half = max(0.5 * float(np.ptp(d)) for d in d_loops)
    return max(0.8 * half / scaling.d_per_h, 1e-3)


__all__ += ["iron_drop", "material_dict", "coercive_guess", "preisach_params"]
