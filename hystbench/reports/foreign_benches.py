"""What the foreign benches (:mod:`hystbench.sim_backend.benches`) and the iron models look like to the
paper's method: theta_hyst at 320 Hz at the paper's amplitude, the force range, the peak flux density
in the coil leg, and the iron's share of the coil's MMF.

    python -m hystbench.reports.foreign_benches              # the per-bench table (markdown)
    python -m hystbench.reports.foreign_benches --materials  # each iron in the nominal presets

Figures, not tests: the tests check the benches against the generator's truth.
"""

from __future__ import annotations

import argparse
import sys
from typing import Any, Mapping

import numpy as np

from ..analysis.method import measure_delays
from ..config import load_material, load_rig
from ..formats.recording import Recording
from ..sim_backend.benches import FOREIGN_BENCHES, bench_truth, foreign_preset
from ..sim_backend.rig import SimulatedRig

__all__ = ["PAPER_AMPLITUDE_A", "operating_point", "bench_rows", "material_rows", "main"]

#: The paper's operating points (A-pp): 1.4 with magnet (Sec. VI), 1.27 without (Sec. V).
PAPER_AMPLITUDE_A = {"ecore_pm": 1.4, "ecore": 1.27}
FREQUENCY_HZ = 320.0
DURATION_S = 0.1


def operating_point(preset: Mapping[str, Any], current_pp_a: float, frequency_hz: float = FREQUENCY_HZ,
                    effects: Mapping[str, Any] | None = None, seed: int = 1) -> dict[str, float]:
    """theta_hyst (deg, with its standard error), force range (N) and coil-leg B range (T) of one
    simulated recording of ``DURATION_S`` at the operating point."""
    rig = SimulatedRig(preset, seed=seed, frequency_hz=frequency_hz, current_pp_a=current_pp_a, effects=effects)
    blocks, b_leg = [], []
    for _ in range(int(round(DURATION_S * rig.fs_hz / 10_000))):
        blocks.append(rig.read(10_000))
        b_leg.append(np.asarray(getattr(rig.actuator, "iron_flux_density_t", np.zeros(0))))
    channels = {c: np.concatenate([b.channels[c] for b in blocks]) for c in blocks[0].channels}
    rec = Recording(None, rig.fs_hz, channels, rig.metadata())
    d = measure_delays(rec)
    b = np.concatenate(b_leg)
    force = channels["force_N"]
    return {"theta_hyst_deg": d.phase_deg("hysteresis"),
            "theta_hyst_se_deg": 360.0 * d.frequency_hz * d.delays_std_s["hysteresis"],
            "force_min_n": float(force.min()), "force_max_n": float(force.max()),
            "b_leg_min_t": float(b.min()), "b_leg_max_t": float(b.max())}


def _amp(x: np.ndarray, fs_hz: float, frequency_hz: float) -> float:
    t = np.arange(x.size) / fs_hz
    return float(abs(2.0 * np.mean((x - x.mean()) * np.exp(-2j * np.pi * frequency_hz * t))))


def iron_share(preset: Mapping[str, Any], current_pp_a: float, frequency_hz: float = FREQUENCY_HZ) -> float:
    """The share of the coil's MMF the static iron takes: 1 - flux / flux with ideal iron (fundamental
    amplitudes, eddy currents off in both)."""
    quiet = {"lamination_eddy_currents": False, "magnet_eddy_currents": False, "sensor_noise": False}
    fluxes = []
    for p, extra in ((preset, {}), (_ideal_iron(preset), {"static_hysteresis": False, "iron_saturation": False})):
        rig = SimulatedRig(p, seed=1, frequency_hz=frequency_hz, current_pp_a=current_pp_a, effects={**quiet, **extra})
        fluxes.append(_amp(rig.read(int(DURATION_S * rig.fs_hz)).channels["flux_Wb"], rig.fs_hz,
                           rig.generator_frequency_hz))
    return 1.0 - fluxes[0] / fluxes[1]


def _ideal_iron(preset: Mapping[str, Any]) -> dict[str, Any]:
    p = {k: v for k, v in preset.items() if k != "_source"}
    p["iron"] = dict(p["iron"], material="M330-50A", linear_mu_r=1e12)
    p.pop("description", None)
    return p


def with_material(nominal: str, material: str) -> dict[str, Any]:
    """The nominal preset with another iron (``iron_saturation`` off for one without saturation)."""
    p = {k: v for k, v in load_rig(nominal).items() if k != "_source"}
    p["iron"] = dict(p["iron"], material=material)
    if load_material(material)["model"] != "preisach-factorised":
        p["effects"] = {k: v for k, v in p["effects"].items() if k != "iron_saturation"}
    return p


def bench_rows(names: list[str] | None = None) -> list[dict[str, Any]]:
    """One row per bench (the nominal rigs first): its truth and its figures at 320 Hz."""
    rows = []
    for name in ["ecore_pm", "ecore"] + list(names or FOREIGN_BENCHES):
        if name in PAPER_AMPLITUDE_A:
            preset, truth = load_rig(name), None
            nominal = name
        else:
            preset, truth = foreign_preset(name), bench_truth(name)
            nominal = truth["nominal"]
        ipp = PAPER_AMPLITUDE_A[nominal]
        rows.append({"bench": name, "current_pp_a": ipp, "truth": truth, **operating_point(preset, ipp)})
    return rows


def material_rows() -> list[dict[str, Any]]:
    """Each shipped E-core iron in the nominal presets: theta_hyst at 320 Hz (and with static
    hysteresis off), and the static iron's MMF share, at the paper's amplitudes."""
    rows = []
    for material in ("M330-50A", "M130-27S", "SiFe-elliptic", "SiFe-rayleigh"):
        for nominal, ipp in PAPER_AMPLITUDE_A.items():
            p = with_material(nominal, material)
            rows.append({"material": material, "rig": nominal, "current_pp_a": ipp,
                         "theta_hyst_deg": operating_point(p, ipp)["theta_hyst_deg"],
                         "theta_hyst_static_off_deg": operating_point(p, ipp, effects={"static_hysteresis": False})[
                             "theta_hyst_deg"],
                         "iron_share": iron_share(p, ipp)})
    return rows


def _fmt_factors(truth: Mapping[str, Any] | None) -> str:
    if truth is None:
        return "(nominal)"
    return ", ".join(f"{k.split('.')[-1].removesuffix('_m').removesuffix('_t').removesuffix('_hz')} "
                     f"x{v:g}" for k, v in truth["factors"].items())


def main(argv: list[str] | None = None) -> int:
    """Print the per-bench table, or (``--materials``) the iron models' figures in the nominal rigs."""
    ap = argparse.ArgumentParser(prog="python -m hystbench.reports.foreign_benches",
                                 description=__doc__.splitlines()[0])
    ap.add_argument("--materials", action="store_true", help="each iron in the nominal presets instead")
    a = ap.parse_args(argv)
    if a.materials:
        print("| material | rig | A-pp | theta_hyst 320 Hz (deg) | static_hysteresis off (deg) | iron MMF share |")
        print("|---|---|---|---|---|---|")
        for r in material_rows():
            print(f"| {r['material']} | {r['rig']} | {r['current_pp_a']:g} | {r['theta_hyst_deg']:.3f} | "
                  f"{r['theta_hyst_static_off_deg']:.3f} | {100 * r['iron_share']:.2f} % |")
        return 0
    print("| bench | iron | factors | instrument fn (Hz), zeta_n | A-pp | theta_hyst 320 Hz (deg) | force (N) | "
          "B coil leg (T) |")
    print("|---|---|---|---|---|---|---|---|")
    for r in bench_rows():
        t = r["truth"]
        preset = load_rig(r["bench"]) if t is None else foreign_preset(r["bench"])
        inst = preset["instrument"]
        print(f"| {r['bench']} | {preset['iron']['material']} | {_fmt_factors(t)} | {inst['fn_hz']:g}, "
              f"{inst['zeta_n']:g} | {r['current_pp_a']:g} | {r['theta_hyst_deg']:.3f} +- "
              f"{r['theta_hyst_se_deg']:.3f} | {r['force_min_n']:.2f} .. {r['force_max_n']:.2f} | "
              f"{r['b_leg_min_t']:.3f} .. {r['b_leg_max_t']:.3f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
