"""Foreign benches: named simulated benches that are NOT our nominal rigs, for the tests and
``python -m benchmarks compensator``.

A real bench differs from the preset it was built after: its dimensions, turns, magnet and airgap
are off by some percent, its iron is another grade or behaves otherwise than the material model,
and its load cell and charge amplifier are not the catalogue's.  Each :class:`ForeignBench` says
how one bench differs from a nominal E-core preset (``ecore`` or ``ecore_pm``): a factor per
geometry key, on the coil's turns and the magnet's remanence (all within 0.8-1.2, different per
bench, not all in one direction), an iron (``M330-50A`` as the nominal, ``M130-27S``, the
complex-permeability ``SiFe-elliptic``, the Rayleigh ``SiFe-rayleigh``) and factors on the
instrument's ``fn_hz`` and ``zeta_n`` (``f0_hz`` and ``zeta_0`` kept: identification corrects the
first two).  The family: for each nominal, one bench per iron, named ``NOMINAL~IRON``
(``ecore_pm~m130``, ``ecore~elliptic``, ...).

:func:`foreign_preset` gives the bench as a checked rig preset whose ``name`` is the nominal's, so
its recordings look like the nominal rig's (as a real bench's would: nobody relabels the rig);
``description`` says what differs.  :func:`bench_truth` gives what the generator knows and a fit
must find: the static force law, the magnet's bias, the instrument, the iron.

The factors were chosen so every bench simulates (no SimulationError) and no channel clips at
0.3-1.5 A-pp and 40-480 Hz (tests/sim_backend/test_foreign_benches.py checks the corners): an
``ecore`` bench's peak force at 1.5 A-pp stays under its 5 N force range, its coil-leg B inside the
Rayleigh region of ``SiFe-rayleigh``.
"""

from __future__ import annotations

import copy
import dataclasses
import math
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any, Mapping

from scipy.constants import mu_0

from ..config import load_material, load_rig
from ..errors import ConfigError
from ..physics.iron import ComplexPermeabilityIron
from ..physics.mec import ECoreMEC
from ..physics.presets import ecore_mec

__all__ = ["ForeignBench", "FOREIGN_BENCHES", "foreign_preset", "bench_truth", "voice_coil_on_load_cell", "IRONS"]

#: A bench's iron (the suffix of its name) -> (material file, lamination thickness m, conductivity S/m):
#: M130-27S comes in 0.27 mm sheets of higher-silicon steel (resistivity ~52 uOhm cm); the SiFe irons
#: in the nominal's 0.5 mm sheets.
IRONS: Mapping[str, tuple[str, float, float]] = MappingProxyType({
    "m330": ("M330-50A", 0.5e-3, 2.2e6),
    "m130": ("M130-27S", 0.27e-3, 1.9e6),
    "elliptic": ("SiFe-elliptic", 0.5e-3, 2.2e6),
    "rayleigh": ("SiFe-rayleigh", 0.5e-3, 2.2e6),
})


@dataclass(frozen=True)
class ForeignBench:
    """How one bench differs from its nominal preset: factors (1.0 = as the preset) on geometry keys,
    on the turns, the remanence and the instrument's keys, and its iron (a key of :data:`IRONS`)."""

    name: str
    nominal: str
    iron: str
    geometry: Mapping[str, float]
    turns: float = 1.0
    remanence: float = 1.0
    instrument: Mapping[str, float] = field(default_factory=dict)

    @property
    def material(self) -> str:
        return IRONS[self.iron][0]

    def factors(self) -> dict[str, float]:
        """Every factor by the preset key it scales (``geometry.airgap_m``, ``coil.turns``, ...)."""
        out = {f"geometry.{k}": v for k, v in self.geometry.items()}
        out["coil.turns"] = self.turns
        if self.nominal == "ecore_pm":
            out["magnet.remanence_t"] = self.remanence
        out.update({f"instrument.{k}": v for k, v in self.instrument.items()})
        return out


def _bench(nominal: str, iron: str, geo: tuple[float, ...], turns: float, remanence: float = 1.0,
           fn: float = 1.0, zeta_n: float = 1.0) -> ForeignBench:
    keys = ("outer_tooth_width_m", "middle_tooth_width_m", "depth_m", "slot_width_m", "slot_height_m",
            "iron_path_length_m", "airgap_m")
    instrument = {k: v for k, v in (("fn_hz", fn), ("zeta_n", zeta_n)) if v != 1.0}
    return ForeignBench(f"{nominal}~{iron}", nominal, iron, MappingProxyType(dict(zip(keys, geo))), turns,
                        remanence, MappingProxyType(instrument))


#: name -> declaration.  Geometry factors in the order: outer tooth, middle tooth, depth, slot width,
#: slot height, iron path, airgap.
FOREIGN_BENCHES: Mapping[str, ForeignBench] = MappingProxyType({b.name: b for b in (
    _bench("ecore_pm", "m330", (1.08, 0.95, 1.05, 0.90, 1.10, 1.15, 1.10), turns=0.92, remanence=1.05),
    _bench("ecore_pm", "m130", (0.92, 1.06, 0.90, 1.12, 0.88, 0.85, 0.88), turns=1.08, remanence=0.90,
           fn=0.96, zeta_n=1.3),
    _bench("ecore_pm", "elliptic", (1.05, 1.10, 0.95, 1.05, 0.95, 1.20, 1.15), turns=1.10, remanence=0.95,
           fn=1.03),
    _bench("ecore_pm", "rayleigh", (0.95, 0.90, 1.12, 0.85, 1.15, 0.90, 0.85), turns=0.90, remanence=1.10,
           fn=0.98, zeta_n=0.8),
    _bench("ecore", "m330", (0.90, 1.05, 1.04, 1.10, 0.90, 1.10, 1.12), turns=0.92),
    _bench("ecore", "m130", (1.10, 0.95, 0.92, 0.88, 1.12, 0.82, 1.15), turns=1.05, fn=1.04, zeta_n=1.3),
    _bench("ecore", "elliptic", (0.95, 1.08, 0.88, 1.15, 1.05, 1.18, 0.95), turns=0.90, fn=0.97),
    _bench("ecore", "rayleigh", (1.12, 0.92, 1.05, 0.92, 0.85, 0.88, 1.20), turns=1.06, fn=1.02, zeta_n=1.3),
)})


def _declared(name: str) -> ForeignBench:
    try:
        return FOREIGN_BENCHES[name]
    except KeyError:
        raise ConfigError(f"unknown foreign bench {name!r}; known: {', '.join(FOREIGN_BENCHES)}") from None


def _describe(bench: ForeignBench) -> str:
    off = ", ".join(f"{k.split('.')[-1]} x{v:g}" for k, v in bench.factors().items() if v != 1.0)
    _, thickness, sigma = IRONS[bench.iron]
    return (f"foreign bench {bench.name}: {bench.nominal} with iron {bench.material} ({thickness * 1e3:g} mm sheets, "
            f"{sigma:g} S/m); {off}")


def foreign_preset(name: str, rig: str | None = None) -> dict[str, Any]:
    """The bench ``name`` as a checked rig preset (``hystbench.config.load_rig`` of a dict).

    ``rig`` (``ecore`` or ``ecore_pm``; default the bench's nominal) builds the bench's other E-core:
    the same core, coil, iron and instrument (the same factors), with or without its magnet, as a
    bench day swaps the magnet in and out of one core.

    Its ``name`` is the nominal rig's (its recordings look like the nominal's, as a real bench's
    would), ``description`` says what differs, and ``_source`` names the bench (errors name it).
    An iron without saturation (complex permeability, Rayleigh) runs without ``iron_saturation``;
    ``linear_mu_r`` and ``incremental_mu_r`` stay the nominal's: the preset is the starting point a
    user would have, not the truth (that is :func:`bench_truth`)."""
    bench = _declared(name)
    if rig is not None and rig != bench.nominal:
        if rig not in ("ecore", "ecore_pm"):
            raise ConfigError(f"foreign bench {name}: its other rig must be ecore or ecore_pm, got {rig!r}")
        bench = dataclasses.replace(bench, nominal=rig)
    nominal = load_rig(bench.nominal)
    p = copy.deepcopy({k: v for k, v in nominal.items() if k != "_source"})
    for key, factor in bench.geometry.items():
        p["geometry"][key] *= factor
    p["coil"]["turns"] = int(round(p["coil"]["turns"] * bench.turns))
    if "magnet" in p:
        p["magnet"]["remanence_t"] *= bench.remanence
    for key, factor in bench.instrument.items():
        p["instrument"][key] *= factor
    material, thickness, sigma = IRONS[bench.iron]
    p["iron"].update(material=material, lamination_thickness_m=thickness, conductivity_s_per_m=sigma)
    if load_material(material)["model"] != "preisach-factorised":
        p["effects"].pop("iron_saturation", None)
    p["description"] = _describe(bench)
    p["_source"] = f"foreign bench {bench.name} (hystbench.sim_backend.benches)"
    return load_rig(p)


def voice_coil_on_load_cell(bench: Mapping[str, Any]) -> dict[str, Any]:
    """The ferrite voice coil (no eddy currents: the paper's instrument identification, Sec. IV)
    mounted on ``bench``'s load cell and charge amplifier: the bench's instrument table and its frame
    modes, not the catalogue voice coil's.  A checked rig preset."""
    coil = {k: v for k, v in load_rig("voicecoil_ferrite").items() if k != "_source"}
    coil["instrument"] = dict(bench["instrument"])
    effects = {k: v for k, v in coil["effects"].items() if k != "frame_resonance"}
    if "frame_resonance" in bench["effects"]:
        effects["frame_resonance"] = bench["effects"]["frame_resonance"]
    coil["effects"] = effects
    coil["_source"] = f"voice coil on the load cell of {bench.get('_source', bench.get('name'))}"
    return load_rig(coil)


def bench_truth(name: str) -> dict[str, Any]:
    """What the generator of bench ``name`` knows, for tests (never a fit's output):

    - ``force_coefficients``: (k0, k1, k2) of the ideal-iron MEC at the bench's airgap, F = k0 + k1 i
      + k2 i^2 (``physics.presets.ecore_mec(preset).force_coefficients(airgap)``);
    - ``force_coefficients_linear_iron``: the same with the iron linearised: for the elliptic iron its
      in-phase permeability 1/(mu0 nu') = |mu_r|^2/mu' (the simulator's N; the loss part nu'' only
      turns the flux, changing its amplitude at second order), else the preset's ``linear_mu_r``
      (and ``incremental_mu_r``), as ``ecore_mec(preset, linear_iron=True)``; ``linear_iron_mu_r``;
    - ``bias_flux_density_t``: the magnet's flux density in the coil leg, ideal iron (0 without magnet);
    - ``instrument``: fn_hz, zeta_n, f0_hz, zeta_0;
    - ``iron_model``, ``material``, ``loss_angle_deg`` (the elliptic iron's, else None), ``factors``."""
    bench = _declared(name)
    preset = foreign_preset(name)
    mec = ecore_mec(preset)
    z = mec.geometry.airgap_m
    material = load_material(preset["iron"]["material"])
    loss = None
    if material["model"] == "complex-permeability":
        iron = ComplexPermeabilityIron.from_config(material)
        loss = iron.loss_angle_deg
        mu_lin = 1.0 / (mu_0 * iron.reluctivity()[0])
        linear = ECoreMEC(mec.geometry, mec.magnet, iron_mu_r=mu_lin)
        mu_lin_report: Any = mu_lin
    else:
        linear = ecore_mec(preset, linear_iron=True)
        mu_lin_report = (preset["iron"]["linear_mu_r"], preset["iron"].get("incremental_mu_r"))
    co = mec.flux_coefficients(z)
    bias = co.coil_leg[1] * mec.magnet_mmf_a / mec.geometry.middle_area_m2
    return {
        "name": bench.name,
        "nominal": bench.nominal,
        "force_coefficients": tuple(float(k) for k in mec.force_coefficients(z)),
        "force_coefficients_linear_iron": tuple(float(k) for k in linear.force_coefficients(z)),
        "linear_iron_mu_r": mu_lin_report,
        "bias_flux_density_t": float(bias) if mec.magnet is not None else 0.0,
        "instrument": {k: float(v) for k, v in preset["instrument"].items()},
        "iron_model": material["model"],
        "material": material["name"],
        "loss_angle_deg": loss,
        "factors": bench.factors(),
        "airgap_m": float(z),
    }


#: The factors' allowed ranges: the build off by up to 20 %; the instrument within what identification
#: corrects (fn a few %, the damping by a third).
LIMITS = MappingProxyType({"instrument.fn_hz": (0.9, 1.1), "instrument.zeta_n": (0.7, 1.5)})


def _check_family() -> None:
    """Import-time guard: every factor within its range (a typo is caught here, not in a test run)."""
    for b in FOREIGN_BENCHES.values():
        for key, v in b.factors().items():
            low, high = LIMITS.get(key, (0.8, 1.2))
            if not (math.isfinite(v) and low <= v <= high):
                raise ConfigError(f"foreign bench {b.name}: factor {key} = {v} outside [{low}, {high}]")


_check_family()
