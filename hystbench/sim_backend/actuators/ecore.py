"""The E-core reluctance actuator (with or without magnet): the MEC with ideal iron, plus the iron's
own MMF drop and the eddy currents, advanced one block at a time (vectorised).

The iron is the one its material file's ``model`` names (:mod:`hystbench.physics.iron`): a Preisach
operator or Rayleigh's law is the nonlinear remainder the fixed point iterates; a complex
permeability is linear and goes into the exactly solved linear part (nu' into N, nu''/omega with
the eddy currents into D, rebuilt whenever the excitation's period changes).  A block whose passes
do not converge is refused as saturated beyond the iron's knee, and below it settled with tied
minor loops closed (:meth:`ECoreActuator._settle_tie`).

The same step runs as numba kernels (:mod:`.ecore_kernel`) when :func:`hystbench.jit.enabled`:
the numpy code here is the reference they are tested against, and the fallback (``KERNEL``)."""

from __future__ import annotations

from typing import Any, Mapping

import numpy as np
from scipy import signal

from ...config import load_material
from ...errors import SimulationError
from ...jit import enabled as jit_enabled
from ...physics.eddy import cylinder_eddy_coefficient, lamination_eddy_coefficient
from ...physics.hysteresis import HysteresisState
from ...physics.iron import ComplexPermeabilityIron, RayleighIron, refuse_saturation
from ...physics.presets import ecore_mec, where
from ...physics.permeance import mu_0
from .base import ActuatorOutput

__all__ = ["ECoreActuator", "IRON_ITERATIONS", "KERNEL"]

#: Which implementation ECoreActuator.step runs, read at every step: None = the numba kernels when
#: hystbench.jit.enabled() (numba importable, HYSTBENCH_JIT not 0), False = the numpy code of this
#: module, True = the kernels.  Tests set it to compare both paths in one process.
KERNEL: bool | None = None

#: Fixed-point passes for the iron's static MMF drop.  The gap carries ~97 % of the MMF, so each
#: pass shrinks the error ~30x away from current reversals (where the inverse branch is stiff,
#: less); the residual stays below ~2e-5 of each channel's range, far below the sensor noise.
#: Derivatives are causal backward differences carrying one sample, so any cut of the stream into
#: blocks gives identical samples; they touch only the few-% iron and eddy terms.
IRON_ITERATIONS = 4
#: Passes when the fixed point starts from the iron's remainder one period earlier (interpolated
#: at the exact fractional period): in steady state two passes reach the same residual.
WARM_PASSES = 2
#: Plain passes before the rig refuses a block beyond the iron's knee or settles a tie below it
#: (ECoreActuator._settle_tie, as many passes again), and the step that counts as converged
#: (relative to the iron's remainder field).
MAX_PASSES = 30
CONVERGED = 1e-3
#: The saturation knee of a material (IEC 61869-2's knee point, on the anhysteretic curve): the
#: flux density beyond which 10 % more B costs 50 % more H.  M330-50A: 1.00 T, M130-27S: 1.43 T.
KNEE_B_RATIO, KNEE_H_RATIO = 1.1, 1.5
#: When the plain passes cycle: an extremum of the Preisach iron's B within this of the turning point
#: it returns to closes that loop (sampled extrema of a periodic B tie to < 1 uT period to period).
TIE_T = 1e-6


def _minor_loop_reluctivity(hysteresis, amplitude_t: float = 0.1) -> float:
    """Chord slope dH/dB of a symmetric minor loop of +-amplitude from the demagnetised state."""
    b = amplitude_t * np.sin(np.linspace(0.0, 4.0 * np.pi, 801))
    h, _ = hysteresis.field(b, hysteresis.initial_state())
    second = slice(400, None)  # the second cycle: the loop is closed
    return float(np.ptp(h[second]) / np.ptp(b[second]))


def _saturation_knee_t(hysteresis) -> float:
    """The smallest B on the anhysteretic curve where KNEE_B_RATIO x B takes KNEE_H_RATIO x H."""
    grid = np.arange(0.01, 2.6, 0.0025)
    h = hysteresis.anhysteretic_field(grid)
    past = hysteresis.anhysteretic_field(KNEE_B_RATIO * grid) >= KNEE_H_RATIO * h
    return float(grid[np.argmax(past)]) if past.any() else np.inf


class ECoreActuator:
    """E-core with optional magnet: the MEC with ideal iron, plus the iron's own MMF drop (material
    model and lamination eddy currents) and the magnet's eddy MMF, solved by fixed-point iteration."""

    has_force = True
    has_flux = True

    def __init__(self, preset: Mapping[str, Any], effects: Mapping[str, Mapping[str, Any]], fs_hz: float):
        self.fs_hz = fs_hz
        self.mec = ecore_mec(preset)
        g = self.mec.geometry
        self.turns = g.coil_turns
        self.area_m2 = g.middle_area_m2
        self.iron_length_m = g.iron_path_length_m
        self.z0_m = g.airgap_m
        co = self.mec.flux_coefficients(self.z0_m)
        self._coil = np.array(co.coil_leg)
        self._magnet = np.array(co.magnet)
        self._outer = np.array(co.outer_tooth)
        d1, d2 = self.mec.port_permeance_derivatives(self.z0_m)
        self._dlam, self._d2lam = d1, d2
        h = 1e-3 * self.z0_m
        self._douter_dz = (np.array(self.mec.flux_coefficients(self.z0_m + h).outer_tooth)
                           - np.array(self.mec.flux_coefficients(self.z0_m - h).outer_tooth)) / (2 * h)
        self.magnet_mmf_a = self.mec.magnet_mmf_a
        iron = preset["iron"]

        self.hysteresis = None
        self._tie: dict[str, float] = {}  # how the iron closes tied loops when the passes cycle
        self._irreversible = "static_hysteresis" in effects
        self._saturation = "iron_saturation" in effects
        material = load_material(iron["material"])
        refuse_saturation(material, effects, where(preset))
        #: the material file's ``model``: which physics the iron follows
        self.iron_model = material["model"]
        self._complex: ComplexPermeabilityIron | None = None
        linear_nu = None  # the iron's reluctivity when it is linear and given by its material
        if self.iron_model == "complex-permeability":
            self._complex = ComplexPermeabilityIron.from_config(material)
            linear_nu = self._complex.reluctivity()[0]
        elif self.iron_model == "rayleigh":
            rayleigh = RayleighIron.from_config(material)
            if self._irreversible:
                self.hysteresis = rayleigh
                self._h_state = self.hysteresis.initial_state()
            else:  # c = 0: the reversible part alone, linear
                linear_nu = rayleigh.nu_i
        elif self._irreversible or self._saturation:
            from ...physics.hysteresis import PreisachHysteresis  # heavy tables only when needed

            self.hysteresis = PreisachHysteresis.from_config(material)
            self._h_state = self.hysteresis.initial_state()
            self._tie = {"close_t": TIE_T}
        self._eddy_coef = 0.0
        if "lamination_eddy_currents" in effects:
            self._eddy_coef = lamination_eddy_coefficient(iron["conductivity_s_per_m"],
                                                          iron["lamination_thickness_m"])
        self._magnet_eddy = 0.0
        if "magnet_eddy_currents" in effects and "magnet" in preset:
            m = preset["magnet"]
            self._magnet_eddy = cylinder_eddy_coefficient(m["conductivity_s_per_m"], m["eddy_radius_m"]) * m["length_m"]
        # nu0: the iron's linear reluctivity, solved exactly; only the rest is iterated, so the
        # closer nu0 is to the slope the iron really shows, the faster the passes converge.
        self._nu0 = 1.0 / (mu_0 * iron["linear_mu_r"]) if linear_nu is None else linear_nu
        if self.hysteresis is not None:
            self._nu0 = _minor_loop_reluctivity(self.hysteresis,
                                                min(0.1, getattr(self.hysteresis, "max_amplitude_t", 0.1)))
        # nu'' of a complex-permeability iron (0 for the others, and with static_hysteresis off):
        # its loss term nu''/omega dB/dt joins the eddy currents' in D, at the excitation's omega
        self._nu_loss = self._complex.reluctivity()[1] if self._complex is not None and self._irreversible else 0.0
        self._omega = 2.0 * np.pi * float(preset["excitation"]["frequency_hz"])  # until the rig tells the period
        self._m = np.array([self._coil, self._magnet]) / self.area_m2  # flux density per MMF
        self._lag = self._linear_part()
        self._b_knee = np.inf  # beyond it the iron's slope outgrows nu0 (only with saturation on)
        if self.hysteresis is not None and self._saturation:
            grid = np.linspace(0.0, 2.6, 1041)
            steep = np.gradient(self.hysteresis.anhysteretic_field(grid), grid) > self._nu0
            self._b_knee = float(grid[np.argmax(steep)]) if steep.any() else np.inf
        #: beyond it the refusal says saturation (inf: the iron's model does not saturate here)
        self.saturation_knee_t = (_saturation_knee_t(self.hysteresis)
                                  if self.hysteresis is not None and self._saturation else np.inf)
        self._material = str(iron["material"])
        self.name = str(preset.get("name"))
        self._where = where(preset)
        self._preset_frequency_hz = float(preset["excitation"]["frequency_hz"])
        self._thermal = effects.get("magnet_thermal_drift")
        comp = effects.get("load_cell_compliance")
        self._compliance = 0.0 if comp is None else 1.0 / float(comp["stiffness_n_per_m"])
        self._prev_drop: np.ndarray | None = None
        # the kernels cover the Preisach iron and every linear iron; Rayleigh's loops stay in numpy
        self._kernel_ok = self.hysteresis is None or hasattr(self.hysteresis, "kernel_tables")
        self._kernel_lag: tuple[_LinearPart, np.ndarray, np.ndarray] | None = None  # lag it was built for
        self._kernel_tables: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None = None
        self._kernel_mode = np.array([self._irreversible, self._saturation], dtype=np.int64)
        #: the iron's flux density in the coil leg over the last block (T)
        self.iron_flux_density_t = np.zeros(0)
        self.set_period(None)

    def dc_flux_wb(self, current_a: float) -> float:
        return float(self._outer @ np.array([self.turns * current_a, self.magnet_mmf_a]))

    def _linear_part(self) -> "_LinearPart":
        """The linear MMF drops at the current excitation's omega (which only a complex permeability
        needs: nu''/omega joins the lamination eddy coefficient in D)."""
        eddy = self._eddy_coef if not self._nu_loss else self._eddy_coef + self._nu_loss / self._omega
        d = np.diag([eddy * self.iron_length_m, self._magnet_eddy])
        n = np.diag([self._nu0 * self.iron_length_m, 0.0])
        return _LinearPart(self._m, n, d, self.fs_hz)

    def set_period(self, samples: float | None) -> None:
        """The excitation's period in samples (None: not periodic: the preset's [excitation]
        frequency stands in for a complex permeability's omega); the rig calls this on every
        change of excitation, which also forgets the last period's iron field."""
        self._period = None if samples is None else float(samples)
        self._history = np.zeros(0)
        if self._nu_loss and self._period is not None:
            omega = 2.0 * np.pi * self.fs_hz / self._period
            if omega != self._omega:
                self._omega = omega
                self._lag = self._lag.rebuilt(self._linear_part())

    def _first_guess(self, n: int) -> tuple[np.ndarray, None, int]:
        """Start of the fixed point: the iron's remainder one (fractional) period earlier, read by
        linear interpolation, when a whole period is known (steady state: WARM_PASSES suffice),
        else zero (IRON_ITERATIONS passes)."""
        if self.hysteresis is None:
            return np.zeros(n), None, 0
        p, hist = self._period, self._history
        if p is None or hist.size < int(np.ceil(p)) + 2:
            return np.zeros(n), None, IRON_ITERATIONS
        pos = hist.size - p + np.mod(np.arange(n), p)  # where sample k0+i stood one period before
        return np.interp(pos, np.arange(hist.size), hist), None, WARM_PASSES

    def _remember(self, h_rest: np.ndarray) -> None:
        if self.hysteresis is not None and self._period is not None:
            keep = int(np.ceil(self._period)) + 2
            self._history = np.concatenate((self._history, h_rest))[-keep:]

    def _newton_step(self, b: np.ndarray, residual: np.ndarray) -> np.ndarray:
        """Fixed-point step on the iron's remainder, damped by the Newton factor where the iron is
        past its knee: there dH/dB (the anhysteretic slope, which the branches approach in
        saturation) outgrows the airgap's dilution and the plain step would diverge."""
        steep = np.abs(b) > self._b_knee
        if not steep.any():
            return residual
        nu_d = np.full_like(b, self._nu0)
        bs = b[steep]
        an = self.hysteresis.anhysteretic_field
        nu_d[steep] = np.maximum(self._nu0, (an(bs + 1e-3) - an(bs - 1e-3)) / 2e-3)
        return residual / (1.0 + (nu_d - self._nu0) * self._lag.instantaneous_gain * self.iron_length_m)

    def _static_field(self, b: np.ndarray, **tie: float):
        """The iron's rate-independent H for the trajectory b, and the state it ends in."""
        return self.hysteresis.field(b, self._h_state, irreversible=self._irreversible,
                                     saturation=self._saturation, **tie)

    def _pass(self, fc: np.ndarray, fm: np.ndarray, h_rest: np.ndarray, **tie: float):
        """One fixed-point pass on the iron's remainder: (B in the coil leg, the new remainder, the
        iron's state at the block's end, whether the step was below CONVERGED)."""
        x, _ = self._lag.run(np.stack([fc - h_rest * self.iron_length_m, fm]))
        h, h_state = self._static_field(x[0], **tie)
        step = self._newton_step(x[0], h - self._nu0 * x[0] - h_rest)
        h_rest = h_rest + step
        return x[0], h_rest, h_state, bool(np.max(np.abs(step)) <= CONVERGED * (np.max(np.abs(h_rest)) + 1.0))

    def _settle_tie(self, fc: np.ndarray, fm: np.ndarray, h_rest: np.ndarray, b: np.ndarray,
                    current_a: np.ndarray):
        """The fixed point when MAX_PASSES plain passes did not converge (every block that converged
        before is untouched, sample for sample).

        Below the iron's knee the plain step cycles at a tie: the Preisach iron's tabulated branches
        close a minor loop to ~1e-3 A/m, not exactly, so loops nested between extrema that tie
        (B sampled at a whole number of samples per period: 250 at 400 Hz) drift apart level by
        level, and where the latest extremum wipes the nest out H jumps by the drift (~0.05 A/m on
        M130-27S after a 20-period warm-up).  Which side the extremum falls on moves with the last
        pass's uT, so the plain step flips between the two for ever, and there is no fixed point.
        The passes go on with tied loops closed (TIE_T: return-point memory at the model's
        resolution): no nest, no jump, and the plain step converges.

        Beyond the knee the block is refused as saturated, as before.  Returns (h_rest, the iron's
        state at the end of the block); raises SimulationError when it does not converge either."""
        peak_b = float(np.max(np.abs(b)))
        if peak_b > self.saturation_knee_t or not self._tie:  # Rayleigh's branches close exactly
            raise self._refusal(peak_b, current_a)
        for _ in range(MAX_PASSES):
            b, h_rest, h_state, converged = self._pass(fc, fm, h_rest, **self._tie)
            if converged:
                return h_rest, h_state
        raise self._refusal(float(np.max(np.abs(b))), current_a)

    def _refusal(self, peak_b_t: float, current_a: np.ndarray) -> SimulationError:
        """The error for a block whose iron field did not converge: saturation only when the iron
        is beyond its knee; else the fixed point's own failure.  Both name the preset's source and
        the operating point."""
        f_hz = self._preset_frequency_hz if self._period is None else self.fs_hz / self._period
        point = (f"at {f_hz:.4g} Hz, coil current up to {np.max(np.abs(current_a)):.3g} A: |B| up to "
                 f"{peak_b_t:.2f} T")
        if peak_b_t > self.saturation_knee_t:
            return SimulationError(
                f"{self.name} ({self._where}): the iron's field does not converge {point}, beyond the "
                f"{self.saturation_knee_t:.2f} T knee of {self._material}: the actuator is driven into "
                "saturation; lower the current")
        knee = (f"below the {self.saturation_knee_t:.2f} T knee of {self._material}"
                if np.isfinite(self.saturation_knee_t) else f"{self._material} has no knee in this model")
        return SimulationError(
            f"{self.name} ({self._where}): the iron's fixed point did not converge {point} ({knee}): "
            "a limit of the simulator, not of the bench; try a slightly different frequency")

    def step(self, t_s: np.ndarray, current_a: np.ndarray, dcurrent_dt: np.ndarray) -> ActuatorOutput:
        if self._kernel_ok and current_a.size and (jit_enabled() if KERNEL is None else KERNEL):
            return self._step_kernel(t_s, current_a, dcurrent_dt)
        fc = self.turns * current_a
        fm = np.full_like(fc, self.magnet_mmf_a)
        dfm = 0.0
        if self._thermal is not None:
            rate = self._thermal["remanence_tc_per_k"] * self._thermal["kelvin_per_s"]
            fm, dfm = fm * (1.0 + rate * t_s), self.magnet_mmf_a * rate
        # The linear part of the iron and the eddy currents are solved exactly by the recursion;
        # only the iron's nonlinear remainder h(B) - nu0 B is iterated (a small loop gain).
        h_rest, h_state, passes = self._first_guess(fc.size)
        for n_pass in range(1, MAX_PASSES + 1 if self.hysteresis is not None else 1):
            b, h_rest, h_state, converged = self._pass(fc, fm, h_rest)
            if n_pass >= passes and converged:
                break
        else:
            if self.hysteresis is not None:
                h_rest, h_state = self._settle_tie(fc, fm, h_rest, b, current_a)
        self._remember(h_rest)
        u = np.stack([fc - h_rest * self.iron_length_m, fm])
        x, lag_state = self._lag.run(u)
        self._h_state, self._lag.state = h_state, lag_state
        self.iron_flux_density_t = x[0]  # B in the coil leg over this block (reports, tests)
        s = u - self._lag.linear_mmf(x)  # (F_coil, F_magnet) as the airgaps see them

        quad = lambda lam: -0.5 * (lam[0] * s[0] ** 2 + 2 * lam[1] * s[0] * s[1] + lam[2] * s[1] ** 2)  # noqa: E731
        force = quad(self._dlam)
        flux = self._outer @ s
        if self._compliance:
            dz = -force * self._compliance  # the gap closes as the load cell yields
            force = force + quad(self._d2lam) * dz
            flux = flux + (self._douter_dz @ s) * dz
        # d(flux)/dt: the coil's N1 di/dt is analytic; the small iron/eddy part numerical (causal).
        drop = np.stack([fc, fm]) - s
        drop_rate = np.diff(drop, axis=1, prepend=drop[:, :1] if self._prev_drop is None
                            else self._prev_drop[:, None]) * self.fs_hz
        self._prev_drop = drop[:, -1].copy()
        dflux = (self._outer[0] * (self.turns * dcurrent_dt - drop_rate[0])
                 + self._outer[1] * (dfm - drop_rate[1]))
        return ActuatorOutput(force, flux, dflux)

    def _kernel_constants(self) -> tuple[np.ndarray, np.ndarray]:
        """The linear part's coefficients as the kernels read them: (lam, q, vec) and the diagonal of
        (N, D) (_linear_part builds them diagonal), rebuilt when set_period rebuilds the linear part."""
        lag = self._lag
        if self._kernel_lag is None or self._kernel_lag[0] is not lag:
            coef = np.concatenate((lag.lam, lag.q.ravel(), lag.vec.ravel())).astype(np.float64)
            nd = np.array([lag.n[0, 0], lag.d[0, 0], lag.d[1, 1]], dtype=np.float64)
            if np.any(lag.n != np.diag([nd[0], 0.0])) or np.any(lag.d != np.diag(nd[1:])):
                raise AssertionError("ecore_kernel.final_run takes N = diag(n, 0) and a diagonal D")
            self._kernel_lag = (lag, coef, nd)
        return self._kernel_lag[1], self._kernel_lag[2]

    def _tables(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The Preisach iron's tables for the kernel (built once: its ``_inverse`` is cached too)."""
        if self._kernel_tables is None:
            self._kernel_tables = self.hysteresis.kernel_tables()
        return self._kernel_tables

    def _step_kernel(self, t_s: np.ndarray, current_a: np.ndarray, dcurrent_dt: np.ndarray) -> ActuatorOutput:
        """:meth:`step` by the numba kernels (same passes, same numbers; see ecore_kernel)."""
        from . import ecore_kernel as kern  # numba compiles (or loads its cache) on the first call

        f64 = np.float64
        fc = np.ascontiguousarray(self.turns * current_a, dtype=f64)
        n = fc.size
        fm = np.full_like(fc, self.magnet_mmf_a)
        dfm = 0.0
        if self._thermal is not None:
            rate = self._thermal["remanence_tc_per_k"] * self._thermal["kelvin_per_s"]
            fm, dfm = np.ascontiguousarray(fm * (1.0 + rate * t_s), dtype=f64), self.magnet_mmf_a * rate
        coef, nd = self._kernel_constants()
        lag = self._lag
        cold = lag.state is None
        y_start = np.zeros(2) if cold else np.ascontiguousarray(lag.state[0], dtype=f64)
        if self.hysteresis is None:
            h_rest = np.zeros(n)
        else:
            p, hist = self._period, self._history
            if p is None or hist.size < int(np.ceil(p)) + 2:
                h_rest, first = np.zeros(n), IRON_ITERATIONS
            else:
                h_rest, first = np.empty(n), WARM_PASSES
                kern.first_guess(np.ascontiguousarray(hist, dtype=f64), float(p), h_rest)
            st = self._h_state
            turns = np.array(st.turns, dtype=f64).reshape(len(st.turns), 2)
            tin, tout = np.empty(turns.shape[0] + n + 2), np.empty(turns.shape[0] + n + 2)
            end, out = np.empty(4), np.empty(3)
            kern.passes(fc, fm, h_rest, first, MAX_PASSES, CONVERGED, coef, y_start, cold,
                        np.ascontiguousarray(turns[:, 0]), np.ascontiguousarray(turns[:, 1]),
                        np.array([st.b_t, st.h_a_per_m, float(st.direction)]), tin, tout, end,
                        *self._tables(), self._kernel_mode, self._b_knee, self._nu0, lag.instantaneous_gain,
                        self.iron_length_m, out)
            if out[0]:
                m = int(end[3])
                h_state = HysteresisState(float(end[0]), float(end[1]), int(end[2]),
                                          tuple(zip(tin[:m].tolist(), tout[:m].tolist())))
            else:  # as step: tied loops closed below the knee, refused beyond it (numpy, rare)
                h_rest, h_state = self._settle_tie(fc, fm, h_rest, np.array([out[2]]), current_a)
            self._remember(h_rest)
            self._h_state = h_state
        force, flux, dflux, iron_b = np.empty(n), np.empty(n), np.empty(n), np.empty(n)
        prev = np.full(2, np.nan) if self._prev_drop is None else self._prev_drop.astype(f64)
        lag_end = np.empty(4)
        kern.final_run(fc, fm, h_rest, self.iron_length_m, coef, y_start, cold, nd, float(self.fs_hz),
                       self._dlam, self._d2lam, self._outer, self._douter_dz, float(self._compliance),
                       float(self.turns), np.ascontiguousarray(dcurrent_dt, dtype=f64), float(dfm), prev,
                       force, flux, dflux, iron_b, lag_end)
        lag.state = (lag_end[:2].copy(), lag_end[2:].copy())
        self._prev_drop = prev
        self.iron_flux_density_t = iron_b
        return ActuatorOutput(force, flux, dflux)


class _LinearPart:
    """Flux densities x = (B_iron, B_magnet) under the linear MMF drops N x + D dx/dt (the iron's
    linear reluctivity and the eddy currents, backward Euler):

        x = M (u - N x - D fs (x[n] - x[n-1]))   =>   x[n] = P x[n-1] + Q u[n]

    with M the flux-density-per-MMF matrix.  P has real eigenvalues in [0, 1), so in its eigenbasis
    the recursion is two scalar first-order filters (scipy.signal.lfilter), exact and stable."""

    def __init__(self, m: np.ndarray, n: np.ndarray, d: np.ndarray, fs_hz: float) -> None:
        self.n, self.d, self.fs_hz = n, d, fs_hz
        k = np.linalg.inv(np.eye(2) + m @ n + m @ d * fs_hz)
        lam, vec = np.linalg.eig(k @ m @ d * fs_hz)
        self.lam, self.vec = lam.real, vec.real
        self.vec_inv = np.linalg.inv(self.vec)
        self.q = self.vec_inv @ (k @ m)
        #: dB_iron[n] / dF_coil[n]: how much this sample's coil MMF moves this sample's iron B
        self.instantaneous_gain = float((k @ m)[0, 0])
        self.state: tuple[np.ndarray, np.ndarray] | None = None  # (y[n-1], x[n-1])

    def rebuilt(self, new: "_LinearPart") -> "_LinearPart":
        """``new`` continuing from this one's committed state: x[n-1] carried over (in flux-density
        coordinates), re-expressed in the new eigenbasis."""
        if self.state is not None:
            x_prev = self.state[1]
            new.state = (new.vec_inv @ x_prev, x_prev.copy())
        return new

    def run(self, u: np.ndarray):
        """x for the MMF sources u (2 x n), from the committed state; returns (x, state after)."""
        w = self.q @ u
        y_prev = w[:, 0] / (1.0 - self.lam) if self.state is None else self.state[0]
        y = np.stack([signal.lfilter([1.0], [1.0, -lam], wj, zi=[lam * yp])[0]
                      for lam, wj, yp in zip(self.lam, w, y_prev)])
        x = self.vec @ y
        self._x_before = self.vec @ y_prev
        return x, (y[:, -1].copy(), x[:, -1].copy())

    def linear_mmf(self, x: np.ndarray) -> np.ndarray:
        """N x + D dx/dt of the trajectory last run (backward difference from the sample before)."""
        dx = np.diff(x, axis=1, prepend=self._x_before[:, None]) * self.fs_hz
        return self.n @ x + self.d @ dx
