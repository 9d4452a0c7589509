"""The independent bench: one recording, and a whole bench day in the recording format.

A recording is computed the way the bench reaches it: the generator has run long enough for every
block to be in periodic steady state, so the current, the actuator's flux and force are solved on
one period (harmonic balance, :mod:`.magnetics`), passed harmonic by harmonic through the
instrument's responses (:mod:`.instrument`), and only then sampled: by an ADC clock a few ppm off
the generator's, each channel at its own skew.  What is not periodic is added in time on the day's
clock (drifts, the magnet's warming, the charge amplifier's decay since its reset, mains, noise).

Effects (design.md's names) are switched per recording by a dict: ``{name: True}`` for this
bench's defaults, ``{name: {param: value}}`` to override, absent/False for off.  With none on, the
bench is ideal apart from its clocks and its current amplifier's bandwidth.
"""

from __future__ import annotations

import json
import math
import zlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from . import instrument as ins
from . import magnetics as mag
from .signals import add_noise, quantise

EFFECT_NAMES: tuple[str, ...] = (
    "static_hysteresis", "lamination_eddy_currents", "magnet_eddy_currents", "iron_saturation",
    "instrument_filter", "frame_resonance", "charge_amp_highpass", "integrator_leak", "channel_skew",
    "force_offset_drift", "magnet_thermal_drift", "load_cell_compliance", "mains_pickup",
    "amplifier_distortion", "sensor_noise", "adc_quantisation", "excess_loss", "magnetic_relaxation",
    "iron_thermal_drift")

#: This bench's own parameterisation of each effect (SI units; names say the unit).
DEFAULTS: dict[str, dict[str, Any]] = {
    "static_hysteresis": {"a_A_per_m_per_T": 1200.0, "beta_per_T": 13.3, "gamma_per_T": 13.3},
    "lamination_eddy_currents": {"sigma_S_per_m": 2.0e6, "thickness_m": 0.35e-3, "layers": 12},
    "magnet_eddy_currents": {"sigma_S_per_m": 6.7e5, "shape_factor": 1.0},
    "iron_saturation": {"knee_T": 1.05, "power": 8.0},
    "instrument_filter": {"fn_Hz": 4450.0, "zeta": 0.012, "lpf_Hz": 31000.0, "lpf_zeta": 1.0},
    "frame_resonance": {"frequency_Hz": 1175.0, "zeta": 0.015, "mass_ratio": 40.0, "coupling": 0.002},
    "charge_amp_highpass": {"tau_s": 4.0, "reset_before_s": 0.5},
    "integrator_leak": {"dc_gain": 2.0e4, "r_feedback_ohm": 4.7e6},
    "channel_skew": {"current_A": 0.5e-6, "force_N": 0.0, "flux_Wb": 0.0, "command_V": 0.0},
    "force_offset_drift": {"rate_N_per_s": 4e-4, "step_N": 0.05, "tau_s": 600.0},
    "magnet_thermal_drift": {"delta_T_K": 12.0, "tau_s": 1500.0, "alpha_per_K": -1.2e-3},
    "load_cell_compliance": {"compliance_m_per_N": 2e-8},
    "mains_pickup": {"frequency_Hz": 50.03, "force_N": 0.02, "flux_Wb": 3e-8, "current_A": 2e-4,
                     "third_harmonic": 0.3},
    "amplifier_distortion": {"c2": 0.004, "c3": 0.012, "full_scale_A": 1.0},
    "sensor_noise": {"current_A": 1e-4, "force_N": 4e-3, "flux_Wb": 4e-9, "command_V": 2e-4,
                     "flicker_corner_Hz": 30.0},
    # the iron's rate dependence, in families of its own: an excess field as a power law in dB/dt
    # (measured exponents run 0.5-0.7; 3 A/m at 100 T/s), and a Cole-Cole relaxation of the reluctivity
    # (a spread of relaxation times, alpha < 1; 3 % of the iron's reluctivity, centred on 1.5 ms)
    "excess_loss": {"field_A_per_m_at_100_T_per_s": 3.0, "exponent": 0.6},
    "magnetic_relaxation": {"share_of_reluctivity": 0.03, "tau_s": 1.5e-3, "alpha": 0.85},
    # the iron warms with the day as the magnet does (a first-order rise), and only its loop follows:
    # the hysteretic field (coercivity) falls by -0.6 %/K, the reluctivity stays
    "iron_thermal_drift": {"delta_T_K": 25.0, "tau_s": 900.0, "loop_per_K": -6e-3},
    "adc_quantisation": {"bits": 16, "current_A": 2.0, "flux_Wb": 2e-4, "command_V": 10.0,
                         "force_N": {"ecore": 10.0, "ecore_pm": 400.0, "voicecoil_ferrite": 10.0}},
}

#: Another parameterisation of an effect, chosen by giving its parameters: the iron's loops as
#: ellipses (a linear iron with a loss angle, tan_delta + tan_delta_per_T x the period's AC flux
#: density: Rayleigh's loss growth, the loop kept an ellipse; the paper's Sec. II B picture) instead
#: of Bouc-Wen's pointed ones.
VARIANTS: dict[str, dict[str, Any]] = {
    "static_hysteresis": {"tan_delta": 0.15, "tan_delta_per_T": 0.5},
}

#: The issue's calibration baseline: what an engineer would model on day one.
BASELINE: dict[str, bool] = {name: True for name in (
    "static_hysteresis", "lamination_eddy_currents", "instrument_filter", "sensor_noise", "adc_quantisation")}

RIGS: tuple[str, ...] = ("voicecoil_ferrite", "ecore", "ecore_pm")
CHANNELS: tuple[str, ...] = ("current_A", "force_N", "flux_Wb", "command_V")


@dataclass(frozen=True)
class BenchConstants:
    """What this bench is, effects aside: its clocks, amplifiers and actuators."""

    adc_clock_ppm: float = 3.1           # the ADC's crystal, off its nominal rate
    generator_clock_ppm: float = -4.7    # the generator's, independently
    amp_gain_a_per_v: float = 0.5        # current amplifier transconductance
    amp_bandwidth_hz: float = 25e3       # its first-order small-signal bandwidth
    voice_coil_bl_n_per_a: float = 2.2   # ferrite voice coil: no iron, no eddy currents
    sense_turns: int = 10
    integrator_r_in_ohm: float = 10e3
    integrator_c_f: float = 100e-9
    grid: int = 256                       # samples per period of the harmonic-balance solve
    ecore: mag.ECoreGeometry = field(default_factory=mag.ECoreGeometry)


def effect_params(effects: Mapping[str, Any] | None) -> dict[str, dict[str, Any]]:
    """The switched-on effects with their parameters; an unknown name or parameter is an error."""
    out: dict[str, dict[str, Any]] = {}
    for name, value in (effects or {}).items():
        if name not in DEFAULTS:
            raise ValueError(f"unknown effect {name!r}; known: {', '.join(EFFECT_NAMES)}")
        if value is False or value is None:
            continue
        params = dict(DEFAULTS[name])
        if isinstance(value, Mapping) and name in VARIANTS and set(value) & set(VARIANTS[name]):
            params = dict(VARIANTS[name])
        if isinstance(value, Mapping):
            unknown = set(value) - set(params)
            if unknown:
                raise ValueError(f"effect {name!r}: unknown parameters {sorted(unknown)}; known: {sorted(params)}")
            params.update(value)
        elif value is not True:
            raise ValueError(f"effect {name!r}: give True, False or a dict of parameters, not {value!r}")
        out[name] = params
    return out


def _rng(seed: int, *parts: Any) -> np.random.Generator:
    """A stream per recording, fixed by the seed and the operating point (not by call order)."""
    return np.random.default_rng([int(seed) & 0xFFFFFFFF, zlib.crc32(repr(parts).encode())])


def _harmonics(wave: np.ndarray) -> np.ndarray:
    return np.fft.rfft(wave)


def _wave(spec: np.ndarray, m: int) -> np.ndarray:
    return np.fft.irfft(spec, m)


def _current(p: dict, bench: BenchConstants, ipp: float, f_hz: float, m: int) -> tuple[np.ndarray, np.ndarray]:
    """(command V, coil current A) on one period: the amplifier's lag, then its output stage."""
    theta = 2 * np.pi * np.arange(m) / m
    u = (ipp / 2) / bench.amp_gain_a_per_v * np.sin(theta)
    k = np.arange(m // 2 + 1)
    lag = 1 / (1 + 1j * k * f_hz / bench.amp_bandwidth_hz)
    i_lin = _wave(_harmonics(bench.amp_gain_a_per_v * u) * lag, m)
    d = p.get("amplifier_distortion")
    if d is not None:
        x = i_lin / d["full_scale_A"]
        i_lin = d["full_scale_A"] * (x + d["c2"] * x * x + d["c3"] * x**3)
    return u, i_lin


def _magnet_factor(p: dict, t_day_s: float) -> float:
    """The magnet's MMF relative to cold: its remanence falls as the coil warms it over the day."""
    d = p.get("magnet_thermal_drift")
    if d is None:
        return 1.0
    rise = d["delta_T_K"] * (1 - math.exp(-max(t_day_s, 0.0) / d["tau_s"]))
    return 1 + d["alpha_per_K"] * rise


def _loop_factor(p: dict, t_day_s: float) -> float:
    """The iron's hysteretic field relative to cold: its coercivity falls as the coil warms it."""
    d = p.get("iron_thermal_drift")
    if d is None:
        return 1.0
    rise = d["delta_T_K"] * (1 - math.exp(-max(t_day_s, 0.0) / d["tau_s"]))
    return max(1 + d["loop_per_K"] * rise, 0.0)


def solve_ecore(p: dict, bench: BenchConstants, current: np.ndarray, f_hz: float, magnet: bool,
                magnet_factor: float = 1.0, loop_factor: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """(outer-tooth flux Wb, force N) on one period, by harmonic balance with fixed-point passes
    over the iron's nonlinear field and the gap's breathing on a compliant load cell."""
    geo = bench.ecore
    m = current.size
    k = np.arange(m // 2 + 1)
    omega = 2 * np.pi * f_hz * k
    area = geo.outer_area_m2
    nu = 1 / (mag.MU0 * geo.iron_mu_r)
    r0 = float(mag.loop_reluctance(geo, geo.gap_m, magnet)[0])
    iron = np.ones(k.size, complex)
    lam = p.get("lamination_eddy_currents")
    if lam is not None:
        iron = mag.ladder_reluctivity_factor(omega, mag.MU0 * geo.iron_mu_r, lam["sigma_S_per_m"],
                                             lam["thickness_m"], int(lam["layers"]))
    rel = p.get("magnetic_relaxation")
    if rel is not None:  # Cole-Cole: nu(w) = nu (1 + r (j w tau)^a / (1 + (j w tau)^a))
        jwt = (1j * omega * rel["tau_s"]) ** rel["alpha"]
        iron = iron * (1 + rel["share_of_reluctivity"] * jwt / (1 + jwt))
    eddy = np.zeros(k.size, complex)
    me = p.get("magnet_eddy_currents")
    if magnet and me is not None:
        g_m = me["sigma_S_per_m"] * geo.magnet_length_m / (4 * np.pi) * me["shape_factor"]
        eddy = 2 * g_m * 1j * omega  # the middle leg carries 2 Phi through the magnet
    mmf = geo.turns * current + (mag.magnet_mmf(geo) * magnet_factor if magnet else 0.0)
    sat, hyst, comp = p.get("iron_saturation"), p.get("static_hysteresis"), p.get("load_cell_compliance")
    exc = p.get("excess_loss")
    elliptic = hyst if hyst is not None and "tan_delta" in hyst else None  # a lossy linear iron instead of Bouc-Wen
    hyst = None if elliptic is not None else hyst

    def impedance(phi: np.ndarray | None) -> np.ndarray:
        """The loop's reluctance per harmonic; an elliptic iron's loss angle grows with the period's
        AC flux density (Rayleigh's loops, taken as ellipses)."""
        loss = np.ones(k.size, complex)
        if elliptic is not None:
            b_ac = 0.0 if phi is None else 0.5 * float(np.ptp(phi)) / area
            loss[1:] += 1j * loop_factor * (elliptic["tan_delta"] + elliptic.get("tan_delta_per_T", 0.0) * b_ac)
        return r0 + geo.iron_path_m * nu / area * iron * loss + eddy

    z = impedance(None)
    phi = _wave(_harmonics(mmf) / z, m)
    g = np.full(m, geo.gap_m)
    for _ in range(200):
        b = phi / area
        extra = np.zeros(m)
        if sat is not None:
            extra += mag.anhysteretic_field(b, nu, sat["knee_T"], sat["power"]) - nu * b
        if hyst is not None:
            extra += loop_factor * mag.periodic_bouc_wen(b, hyst["a_A_per_m_per_T"], hyst["beta_per_T"],
                                                         hyst["gamma_per_T"])
        if exc is not None:  # dB/dt from the period's spectrum
            rate = _wave(_harmonics(b) * 1j * omega, m) / 100.0
            extra += exc["field_A_per_m_at_100_T_per_s"] * np.sign(rate) * np.abs(rate) ** exc["exponent"]
        dr = np.zeros(m)
        if comp is not None:
            force = mag.gap_force(geo, phi, g, magnet)
            g = geo.gap_m - comp["compliance_m_per_N"] * force
            dr = mag.loop_reluctance(geo, g, magnet)[0] - r0
        if elliptic is not None:
            z = impedance(phi)
        rhs = mmf - geo.iron_path_m * extra - dr * phi
        new = _wave(_harmonics(rhs) / z, m)
        step = float(np.max(np.abs(new - phi)))
        phi = phi + 0.8 * (new - phi)
        if step < 1e-12 * max(float(np.max(np.abs(phi))), 1e-30):
            break
        if sat is None and hyst is None and comp is None and exc is None and not (
                elliptic and elliptic.get("tan_delta_per_T")):
            break
    return phi, mag.gap_force(geo, phi, g, magnet)


def _sample(wave: np.ndarray, theta: np.ndarray, fine: int = 8192) -> np.ndarray:
    """The periodic waveform at the sample phases: band-limited upsampling, then interpolation."""
    spec = _harmonics(wave) * (fine / wave.size)
    up = np.fft.irfft(spec, fine)
    grid = 2 * np.pi * np.arange(fine + 1) / fine
    return np.interp(np.mod(theta, 2 * np.pi), grid, np.append(up, up[0]))


def simulate_recording(rig: str, frequency_hz: float, current_pp_a: float, *, effects: Mapping[str, Any],
                       fs_hz: float = 100e3, periods: float = 48, start_time_s: float = 0.0, seed: int,
                       bench: BenchConstants | None = None) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """One recording: ``(columns, sidecar)``; columns ``time_s`` (nominal ADC time from 0),
    ``current_A``, ``force_N``, ``flux_Wb`` (E-cores only: the voice coil has no sense coil) and
    ``command_V``; the sidecar holds what a real bench's would (never the effects or the seed)."""
    if rig not in RIGS:
        raise ValueError(f"unknown rig {rig!r}; known: {', '.join(RIGS)}")
    if not (0 < frequency_hz < fs_hz / 2) or current_pp_a < 0 or periods <= 0:
        raise ValueError(f"bad operating point: {frequency_hz} Hz, {current_pp_a} A-pp, {periods} periods")
    bench = bench or BenchConstants()
    p = effect_params(effects)
    rng = _rng(seed, rig, float(frequency_hz), float(current_pp_a), float(start_time_s))
    m = bench.grid
    f_true = frequency_hz * (1 + bench.generator_clock_ppm * 1e-6)
    n = int(round(periods * fs_hz / frequency_hz))
    t_nom = np.arange(n) / fs_hz
    t_true = np.arange(n) / (fs_hz * (1 + bench.adc_clock_ppm * 1e-6))
    phase0 = rng.uniform(0, 2 * np.pi)

    command, current = _current(p, bench, current_pp_a, f_true, m)
    if rig == "voicecoil_ferrite":
        flux, force = None, bench.voice_coil_bl_n_per_a * current
    else:
        magnet = rig == "ecore_pm"
        mid_day = start_time_s + n / fs_hz / 2
        flux, force = solve_ecore(p, bench, current, f_true, magnet, _magnet_factor(p, mid_day) if magnet else 1.0,
                                  _loop_factor(p, mid_day))

    # the instrument, harmonic by harmonic; the charge amplifier's DC handled in time below
    k = np.arange(m // 2 + 1)
    omega = 2 * np.pi * f_true * k
    fi, fr = p.get("instrument_filter"), p.get("frame_resonance")
    h_force = ins.load_cell_frame_response(omega, fi["fn_Hz"] if fi else None, fi["zeta"] if fi else 0.0, fr)
    h_force = h_force * ins.charge_amp_response(omega, fi["lpf_Hz"] if fi else None, fi["lpf_zeta"] if fi else 1.0,
                                                None)
    hp = p.get("charge_amp_highpass")
    if hp is not None:
        h_force = h_force * ins.charge_amp_response(omega, None, 1.0, hp["tau_s"])
    spec_f = _harmonics(force) * h_force
    force_dc = float(np.real(spec_f[0])) / m
    spec_f[0] = 0.0
    leak = p.get("integrator_leak")
    h_flux = ins.integrator_response(omega, bench.integrator_r_in_ohm, bench.integrator_c_f,
                                     leak["dc_gain"] if leak else None, leak["r_feedback_ohm"] if leak else None)

    skew = p.get("channel_skew", {})
    theta = phase0 + 2 * np.pi * f_true * t_true
    def at(name: str, wave: np.ndarray) -> np.ndarray:
        return _sample(wave, theta - 2 * np.pi * f_true * float(skew.get(name, 0.0)))

    cols: dict[str, np.ndarray] = {"time_s": t_nom}
    cols["current_A"] = at("current_A", current)
    force_ac = at("force_N", _wave(spec_f, m))
    if hp is not None:  # reset (operate) reset_before_s before the recording, the load applied since
        dc = force_dc * np.exp(-(t_true + hp["reset_before_s"]) / hp["tau_s"])
    else:
        dc = np.full(n, force_dc)
    cols["force_N"] = force_ac + dc
    if flux is not None:
        cols["flux_Wb"] = at("flux_Wb", _wave(_harmonics(flux) * h_flux, m))
    cols["command_V"] = at("command_V", command)

    t_day = start_time_s + t_true
    drift = p.get("force_offset_drift")
    if drift is not None:
        cols["force_N"] = cols["force_N"] + drift["rate_N_per_s"] * t_day + drift["step_N"] * (
            1 - np.exp(-t_day / drift["tau_s"]))
    mains = p.get("mains_pickup")
    if mains is not None:
        wm = 2 * np.pi * mains["frequency_Hz"] * t_day
        hum = np.sin(wm + 0.7) + mains["third_harmonic"] * np.sin(3 * wm + 1.9)
        for name in ("force_N", "flux_Wb", "current_A"):
            if name in cols:
                cols[name] = cols[name] + mains[name] * hum
    noise = p.get("sensor_noise")
    if noise is not None:
        for name in CHANNELS:
            if name in cols:
                cols[name] = add_noise(cols[name], noise[name], noise["flicker_corner_Hz"], fs_hz, rng)
    adc = p.get("adc_quantisation")
    if adc is not None:
        for name in CHANNELS:
            if name in cols:
                rng_fs = adc[name][rig] if isinstance(adc[name], Mapping) else adc[name]
                cols[name] = quantise(cols[name], float(rng_fs), int(adc["bits"]))

    sidecar: dict[str, Any] = {"rig": rig, "frequency_Hz": float(frequency_hz), "sample_rate_Hz": float(fs_hz),
                               "current_pp_A": float(current_pp_a), "start_time_s": float(start_time_s)}
    if flux is not None:
        sidecar["sense_turns"] = bench.sense_turns
    return cols, sidecar


VOICE_COIL_FREQS_HZ: tuple[float, ...] = (40.0, 80.0, 160.0, 320.0, 640.0, 1000.0, 1500.0, 2000.0, 3000.0)
E_CORE_FREQS_HZ: tuple[float, ...] = (40.0, 80.0, 160.0, 320.0, 480.0)


def bench_day_plan() -> list[tuple[str, float, float]]:
    """The issue's day, in the order played: (rig, frequency Hz, current A-pp)."""
    plan = [("voicecoil_ferrite", f, 1.0) for f in VOICE_COIL_FREQS_HZ]
    plan += [("ecore", f, 1.27) for f in E_CORE_FREQS_HZ]
    plan += [("ecore_pm", f, i) for i in (0.7, 1.4) for f in E_CORE_FREQS_HZ]
    return plan


def shuffled_blocks(plan: list[tuple[str, float, float]], seed: int) -> list[tuple[str, float, float]]:
    """``plan`` with the frequencies of each block (consecutive points of one rig and current) in a
    random order: the day's clock then no longer runs with the frequency, so a slow change along the
    day cannot pass for a smooth frequency dependence."""
    rng = np.random.default_rng(seed)
    out, start = [], 0
    while start < len(plan):
        end = start
        while end < len(plan) and plan[end][::2] == plan[start][::2]:
            end += 1
        out += [plan[start + k] for k in rng.permutation(end - start)]
        start = end
    return out


def _write_csv(path: Path, cols: Mapping[str, np.ndarray], rows_per_block: int = 4096) -> None:
    """The bytes ``np.savetxt`` writes (time to 1 ns, each channel to 10 digits), a block of rows per
    format operation: savetxt formats row by row, and was a tenth of a diagnosed day's time."""
    names = list(cols)
    data = np.column_stack([cols[k] for k in names])
    row = ",".join(["%.9f"] + ["%.10g"] * (len(names) - 1)) + "\n"
    with open(path, "w") as fh:
        fh.write(",".join(names) + "\n")
        for start in range(0, data.shape[0], rows_per_block):
            block = data[start:start + rows_per_block]
            fh.write((row * block.shape[0]) % tuple(block.ravel().tolist()))


def write_bench_day(folder: str | Path, *, effects: Mapping[str, Any], seed: int, fs_hz: float = 100e3,
                    periods: float = 48, pause_s: float = 20.0, swap_s: float = 300.0,
                    plan: list[tuple[str, float, float]] | None = None,
                    bench: BenchConstants | None = None) -> list[Path]:
    """Write a whole bench day into ``folder`` (one CSV + JSON per recording, one clock for all:
    ``pause_s`` between points, ``swap_s`` between rigs); returns the stems written."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    clock, last_rig, stems = 0.0, None, []
    for rig, f, ipp in plan or bench_day_plan():
        if last_rig is not None:
            clock += swap_s if rig != last_rig else pause_s
        cols, side = simulate_recording(rig, f, ipp, effects=effects, fs_hz=fs_hz, periods=periods,
                                        start_time_s=clock, seed=seed, bench=bench)
        stem = folder / f"{rig}_{f:g}Hz_{ipp:g}App"  # not with_suffix: '1.27App' has a dot
        _write_csv(stem.parent / (stem.name + ".csv"), cols)
        (stem.parent / (stem.name + ".json")).write_text(json.dumps(side, indent=2) + "\n")
        stems.append(stem)
        clock += cols["time_s"].size / fs_hz
        last_rig = rig
    return stems
