"""The iron of a material file, by its ``model``: a Preisach operator, Rayleigh's law, or a complex
permeability.  :func:`iron_model` builds the one a material file names.

``preisach-factorised`` (:class:`~.hysteresis.PreisachHysteresis`): static hysteresis fitted to
measured loops, saturation included.

``rayleigh`` (:class:`RayleighIron`): rate-independent hysteresis in the Rayleigh region (IEC
60050-221-03-32: B/mu0 = (mu_i + v Hpeak) H +- v/2 (Hpeak^2 - H^2)), run with B as the input.  From a
reversal (B_r, H_r) moving in direction s = +-1 the branch is

    H = H_r + nu_i (B - B_r) - s c/2 (B - B_r)^2,    nu_i = 1 / (mu0 mu_i),  c = v / (mu0^2 mu_i^3),

the IEC law inverted to first order in v Hpeak / mu_i (the small-v approximation).  With the
wiping-out rule and return-point memory of :func:`~.hysteresis._run` (Madelung's rules), a loop of
B amplitude Bm about any point has the peak field Hm = nu_i Bm - c Bm^2 (amplitude reluctivity
nu_i - c Bm, linear in Bm: the amplitude permeability grows with the amplitude), the half-width
c (Bm^2 - B^2) between its branches at B, and so the area (4/3) c Bm^3 per cycle (Rayleigh's cube
law).  The initial curve is H = nu_i B - c B |B|: what continuity needs where a branch from it is
wiped out at -B_r (the loops' tips lie on it).  Its slope nu_i - 2 c |B| and a branch's slope
nu_i - c |B - B_r| both reach 0 at amplitude nu_i / (2 c) = mu0 mu_i^2 / (2 v); the material file
declares the Rayleigh region ``region_t`` below that, loops wider than it are refused, and beyond
it the initial curve goes on straight with its slope there: the path to a magnet's bias, about which
the loops again follow the law.  No saturation (``iron_saturation`` is refused with this iron);
``static_hysteresis`` off leaves the reversible part, H = nu_i B.

``complex-permeability`` (:class:`ComplexPermeabilityIron`): mu_r = mu' - j mu'', so
nu = 1 / (mu0 mu_r) = nu' + j nu'' and, at the excitation's angular frequency omega,

    H = nu' B + (nu'' / omega) dB/dt,

whose loops under a sinusoidal B are ellipses with B behind H by the loss angle delta, tan(delta) =
mu''/mu' = nu''/nu'; the paper's Sec. II B models its iron this way ("the elliptic behavior of minor
loops ... translated to a complex impedance model").  The material gives the permeability at the
excitation's frequency, whatever it is: the loss per cycle, pi nu'' Bm^2, does not depend on the
frequency (hysteresis-like); the harmonics of a distorted B see nu'' times their order (the
derivative's), not nu''.  It is linear: no saturation (``iron_saturation`` is refused) and, with
``static_hysteresis`` off, lossless (nu'' = 0, nu' kept).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Mapping, Union

import numpy as np
from numpy.typing import ArrayLike
from scipy.constants import mu_0

from ..config.presets import check_material
from ..errors import ConfigError
from .hysteresis import HysteresisState, PreisachHysteresis, _run, _Work

__all__ = ["RayleighIron", "ComplexPermeabilityIron", "IronModel", "iron_model", "refuse_saturation"]



def _checked(material: Mapping[str, Any], model: str) -> dict[str, Any]:
    """The material file checked again, refused unless it is of ``model``."""
    m = check_material(material)
    if m["model"] != model:
        raise ConfigError(f"{m['_source']}: model {m['model']!r} is not {model!r}")
    return m

class RayleighIron:
    """Rayleigh's law with B as input, with the interface the E-core uses from
    :class:`~.hysteresis.PreisachHysteresis` (see the module docstring for the law)."""

    def __init__(self, initial_mu_r: float, hysteresis_coefficient_m_per_a: float, region_t: float,
                 source: str = "rayleigh") -> None:
        self.initial_mu_r = float(initial_mu_r)
        self.hysteresis_coefficient_m_per_a = float(hysteresis_coefficient_m_per_a)
        self.source = source
        #: nu_i (A/m per T), the initial (and reversible) reluctivity
        self.nu_i = 1.0 / (mu_0 * self.initial_mu_r)
        #: c (A/m per T^2): a branch's reluctivity falls by c per tesla of excursion
        self.c = self.hysteresis_coefficient_m_per_a / (mu_0**2 * self.initial_mu_r**3)
        #: the amplitude where a branch's slope dH/dB = nu_i - c |B - B_r| reaches 0
        self.zero_slope_amplitude_t = math.inf if self.c == 0.0 else self.nu_i / (2.0 * self.c)
        if not 0.0 < region_t < self.zero_slope_amplitude_t:
            raise ConfigError(f"{source} [rayleigh] region_t: must be in (0, {self.zero_slope_amplitude_t:.4g}) T, "
                              f"got {region_t!r}")
        #: the largest loop amplitude simulated (the declared Rayleigh region)
        self.max_amplitude_t = float(region_t)
        self._h_knee = self.nu_i * region_t - self.c * region_t**2  # the initial curve at the region's end
        self._nu_beyond = self.nu_i - 2.0 * self.c * region_t  # and its slope there, kept beyond (> 0)
        self._work = _Work()

    @classmethod
    def from_config(cls, material: Mapping[str, Any]) -> "RayleighIron":
        """From ``hystbench.config.load_material(name)`` (checked again here)."""
        m = _checked(material, "rayleigh")
        r = m["rayleigh"]
        return cls(r["initial_mu_r"], r["hysteresis_coefficient_m_per_a"], r["region_t"], m["_source"])

    def initial_state(self) -> HysteresisState:
        """Demagnetised: B = 0, H = 0, nothing remembered."""
        return HysteresisState()

    @property
    def small_signal_dh_db(self) -> float:
        """dH/dB of the reversible part (A/m per T): nu_i."""
        return self.nu_i

    def anhysteretic_field(self, b: ArrayLike) -> np.ndarray:
        """H (A/m) with static hysteresis switched off: the reversible part nu_i B."""
        return self.nu_i * np.asarray(b, float)

    def virgin_field(self, b: ArrayLike) -> np.ndarray:
        """The initial curve H(B) from the demagnetised state (A/m), odd in B."""
        b = np.asarray(b, float)
        a = np.abs(b)
        inside = self.nu_i * a - self.c * a * a
        beyond = self._h_knee + self._nu_beyond * (a - self.max_amplitude_t)
        return np.sign(b) * np.where(a <= self.max_amplitude_t, inside, beyond)

    def _branch(self, b_r, h_r, s, b, starts=None):
        if starts is not None:
            lens = np.diff(np.append(starts, b.size))
            b_r, h_r, s = np.repeat(b_r, lens), np.repeat(h_r, lens), np.repeat(s, lens)
        d = s * (b - b_r)  # the excursion from the reversal, >= 0 along a branch
        # entries standing in for the initial curve come as (0, 0) and are overwritten by _run
        real = (b_r != 0.0) | (h_r != 0.0)
        if d.size and real.any():
            widest = float(np.max(np.where(real, d, 0.0)))
            if widest > 2.0 * self.max_amplitude_t * (1.0 + 1e-9):
                raise ConfigError(
                    f"{self.source} [rayleigh] region_t: a loop of B amplitude {widest / 2:.4g} T is outside the "
                    f"Rayleigh region, whose largest amplitude is {self.max_amplitude_t:.4g} T (a branch's slope "
                    f"dH/dB reaches 0 at {self.zero_slope_amplitude_t:.4g} T): lower the current")
        return h_r + s * d * (self.nu_i - 0.5 * self.c * d)

    def field(self, b_t: ArrayLike, state: HysteresisState, *, irreversible: bool = True, saturation: bool = True
              ) -> tuple[np.ndarray, HysteresisState]:
        """H (A/m) along the flux-density trajectory b_t (T), continuing from ``state``.

        ``irreversible=False`` gives the reversible part nu_i B (and a state without memory: a
        lossless iron remembers nothing); ``saturation`` is accepted for the interface and means
        nothing here (the law has no saturation; the actuators refuse ``iron_saturation``)."""
        if not irreversible:
            b = np.asarray(b_t, float)
            h = self.nu_i * b
            if b.size == 0:
                return h, state
            return h, HysteresisState(float(b[-1]), float(h[-1]), 0, ())
        return _run(b_t, state, 0, self._branch, self.virgin_field, self._work)  # closed form: no closure


@dataclass(frozen=True)
class ComplexPermeabilityIron:
    """Linear iron with mu_r = mu' - j mu'' (see the module docstring): elliptic B-H loops."""

    mu_r_real: float
    loss_angle_deg: float
    source: str = "complex-permeability"

    @classmethod
    def from_config(cls, material: Mapping[str, Any]) -> "ComplexPermeabilityIron":
        """From ``hystbench.config.load_material(name)`` (checked again here)."""
        m = _checked(material, "complex-permeability")
        p = m["permeability"]
        return cls(p["mu_r_real"], p["loss_angle_deg"], m["_source"])

    @property
    def mu_r_imag(self) -> float:
        """mu'' = mu' tan(delta)."""
        return self.mu_r_real * math.tan(math.radians(self.loss_angle_deg))

    def reluctivity(self, lossy: bool = True) -> tuple[float, float]:
        """(nu', nu'') of nu = 1 / (mu0 (mu' - j mu'')), A/m per T; ``lossy=False``: nu'' = 0."""
        mu = complex(self.mu_r_real, -self.mu_r_imag)
        nu = 1.0 / (mu_0 * mu)
        return float(nu.real), float(nu.imag) if lossy else 0.0

    def field(self, b: ArrayLike, db_dt: ArrayLike, omega_rad_s: float, *, lossy: bool = True) -> np.ndarray:
        """H = nu' B + (nu'' / omega) dB/dt (A/m), omega the excitation's angular frequency."""
        nu_re, nu_im = self.reluctivity(lossy)
        return nu_re * np.asarray(b, float) + (nu_im / omega_rad_s) * np.asarray(db_dt, float)


#: What :func:`iron_model` returns.
IronModel = Union[PreisachHysteresis, RayleighIron, ComplexPermeabilityIron]


def iron_model(material: Mapping[str, Any]) -> IronModel:
    """The iron a material file (``hystbench.config.load_material``) describes, by its ``model``."""
    m = check_material(material)
    if m["model"] == "rayleigh":
        return RayleighIron.from_config(m)
    if m["model"] == "complex-permeability":
        return ComplexPermeabilityIron.from_config(m)
    return PreisachHysteresis.from_config(m)


def refuse_saturation(material: Mapping[str, Any], effects: Mapping[str, Any], where: str) -> None:
    """``iron_saturation`` on with an iron whose model has no saturation is refused, not ignored: the
    effect would be named as on (in the sidecar, by diagnosis) while nothing saturates."""
    model = material.get("model", "preisach-factorised")
    if "iron_saturation" in effects and model != "preisach-factorised":
        raise ConfigError(
            f"{where} [effects] iron_saturation: the iron {material.get('name', '')!r} "
            f"({material.get('_source', 'material')}) is model {model!r}, which has no saturation; switch "
            f"the effect off (remove [effects.iron_saturation]) or choose a preisach-factorised material")
