"""The E-core reluctance actuator (with or without magnet): the MEC with ideal iron, plus the iron's
own MMF drop and the eddy currents, advanced one block at a time (vectorised).

The iron is the one its material file's ``model`` names (:mod:`hystbench.physics.iron`): a Preisach
operator or Rayleigh's law is the nonlinear remainder the fixed point iterates; a complex
permeability is linear and goes into the exactly solved linear part (nu' into N, nu''/omega with
the eddy currents into D, rebuilt whenever the excitation's period changes).  The iron's rate terms
beyond the classical eddy field (``excess_loss``, ``magnetic_relaxation``:
:mod:`hystbench.physics.rate_dependence`) join the iterated remainder, the step damped by their own
slope (the excess field is steep at slow rates), in the passes (numpy and kernel alike; the
sample-by-sample solve does not know them, so a block the passes cannot settle is refused).  Where the passes
stall (the iron is steep at a reversal deep in saturation) the block is solved sample by sample, which
converges over the whole current range (:meth:`ECoreActuator._solve_sequential`): every block of an
excitation whose current can take the iron beyond its knee (decided from the commanded current, so
the same whatever the cut into blocks), and a block whose passes stalled, with the rest of its
excitation.  Beyond the field range of the material's model the block is refused, not invented.

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
from ...physics.iron_thermal import IronThermal, iron_thermal
from ...physics.rate_dependence import RateDependence, rate_dependence
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
#: Plain passes before the block is solved sample by sample (ECoreActuator._solve_sequential), and
#: the step that counts as converged (relative to the iron's remainder field).
MAX_PASSES = 30
CONVERGED = 1e-3
#: The saturation knee of a material (IEC 61869-2's knee point, on the anhysteretic curve): the
#: flux density beyond which 10 % more B costs 50 % more H.  M330-50A: 1.00 T, M130-27S: 1.43 T.
KNEE_B_RATIO, KNEE_H_RATIO = 1.1, 1.5


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


def drop_rate_of(drop: np.ndarray, prev: np.ndarray | None, fs_hz: float) -> tuple[np.ndarray, np.ndarray]:
    """The rate of the MMF drops ``drop`` (2, n), a causal second-order backward difference (3 r_k - 4
    r_k-1 + r_k-2) / 2T, and the history the next block needs: ``prev`` holds the last block's last
    two samples (r0, r1 of the last, then of the one before), NaN where there was none; the rig's first
    sample has rate 0, its second a first-order difference.  A first-order difference alone lags by
    half a sample: the sense coil's voltage then put 0.6 % on the hysteresis delay at 160 Hz."""
    hist = np.full(4, np.nan) if prev is None else np.asarray(prev, dtype=float)
    ext = np.concatenate([np.array([[hist[2]], [hist[3]]]), np.array([[hist[0]], [hist[1]]]), drop], axis=1)
    r, r1, r2 = ext[:, 2:], ext[:, 1:-1], ext[:, :-2]
    first = (r - r1) * fs_hz
    rate = np.where(np.isnan(r2), first, (3.0 * r - 4.0 * r1 + r2) * (0.5 * fs_hz))
    rate = np.where(np.isnan(r1), 0.0, rate)
    last = ext[:, -2:]  # (2, 2): the one before, the last
    return rate, np.array([last[0, 1], last[1, 1], last[0, 0], last[1, 0]])


class ECoreActuator:
    """E-core with optional magnet: the MEC with ideal iron, plus the iron's own MMF drop (material
    model and lamination eddy currents) and the magnet's eddy MMF, solved by fixed-point iteration."""

    has_force = True
    has_flux = True
    sets_current = False

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
        self._eddy_coef = 0.0
        if "lamination_eddy_currents" in effects:
            self._eddy_coef = lamination_eddy_coefficient(iron["conductivity_s_per_m"],
                                                          iron["lamination_thickness_m"])
        #: the iron's rate dependence beyond the classical eddy field (excess_loss, magnetic_relaxation):
        #: nonlinear or with a memory of its own, so it joins the iterated remainder, not the linear part
        self._rate: RateDependence | None = rate_dependence(effects, fs_hz)
        #: the iron's static field follows its temperature along the day (iron_thermal_drift): a scale
        #: per sample on what the iron needs, so it too joins the iterated remainder (a complex
        #: permeability's loss term, in the linear part's D, keeps its value)
        self._iron_thermal: IronThermal | None = iron_thermal(effects)
        self._iron_scale: np.ndarray | None = None  # the block's scale (None: off)
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
        #: B in the coil leg per (coil, magnet) MMF at DC with the linear iron: what the passes start
        #: from, used to tell which blocks can take the iron beyond its knee (_beyond_knee)
        self._b_dc = (np.linalg.inv(np.eye(2) + self._m @ self._lag.n) @ self._m)[0]
        self._b_knee = np.inf  # beyond it the iron's slope outgrows nu0 (only with saturation on)
        if self.hysteresis is not None and self._saturation:
            grid = np.linspace(0.0, 2.6, 1041)
            steep = np.gradient(self.hysteresis.anhysteretic_field(grid), grid) > self._nu0
            self._b_knee = float(grid[np.argmax(steep)]) if steep.any() else np.inf
        #: where the iron's saturation knee is (inf: the iron's model does not saturate here)
        self.saturation_knee_t = (_saturation_knee_t(self.hysteresis)
                                  if self.hysteresis is not None and self._saturation else np.inf)
        #: the largest |B| the saturating iron is modelled to (PreisachHysteresis.max_flux_density_t):
        #: a block beyond it is refused, not invented
        self.max_flux_density_t = (float(self.hysteresis.max_flux_density_t)
                                   if self._saturation and hasattr(self.hysteresis, "max_flux_density_t") else np.inf)
        self._material = str(iron["material"])
        self.name = str(preset.get("name"))
        self._where = where(preset)
        self._preset_frequency_hz = float(preset["excitation"]["frequency_hz"])
        self._thermal = effects.get("magnet_thermal_drift")
        comp = effects.get("load_cell_compliance")
        self._compliance = 0.0 if comp is None else 1.0 / float(comp["stiffness_n_per_m"])
        self._prev_drop: np.ndarray | None = None
        self._rest_tail = np.full(2, np.nan)  # the iron's remainder at the last two samples (NaN: none yet)
        self._primed = False  # the sample-by-sample solve compiled (_prime_sequential)
        # the kernels cover the Preisach iron (its rate terms and temperature too) and every linear iron
        # without them; Rayleigh's loops, and a linear iron's rate terms or temperature, stay in numpy
        self._kernel_ok = ((self.hysteresis is None and self._rate is None and self._iron_thermal is None)
                           or hasattr(self.hysteresis, "kernel_tables"))
        #: the sample-by-sample solve (where the passes stall) knows no rate terms nor the loop's temperature:
        #: with them a block the passes cannot settle is refused
        self._sequential_ok = self._kernel_ok and self._rate is None and self._iron_thermal is None
        #: whether the iron has a remainder to iterate (a static loop, rate terms, a drifting loop)
        self._iterated = self.hysteresis is not None or self._rate is not None or self._iron_thermal is not None
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
        self._by_sample = False  # the passes first: they converge below saturation
        if self._nu_loss and self._period is not None:
            omega = 2.0 * np.pi * self.fs_hz / self._period
            if omega != self._omega:
                self._omega = omega
                self._lag = self._lag.rebuilt(self._linear_part())

    def _first_guess(self, n: int) -> tuple[np.ndarray, None, int]:
        """Start of the fixed point: the iron's remainder one (fractional) period earlier, read by
        linear interpolation, when a whole period is known (steady state: WARM_PASSES suffice),
        else zero (IRON_ITERATIONS passes)."""
        if not self._iterated:
            return np.zeros(n), None, 0
        p, hist = self._period, self._history
        if p is None or hist.size < int(np.ceil(p)) + 2:
            return np.zeros(n), None, IRON_ITERATIONS
        pos = hist.size - p + np.mod(np.arange(n), p)  # where sample k0+i stood one period before
        return np.interp(pos, np.arange(hist.size), hist), None, WARM_PASSES

    def _remember(self, h_rest: np.ndarray) -> None:
        """The block's remainder: the last period's (the next first guess) and the last two samples'
        (where the sample-by-sample solve starts: one sample before the block's last, in _rest_before)."""
        if self._iterated:
            self._rest_tail = np.concatenate((self._rest_tail, h_rest[-2:]))[-2:]
            if self._period is not None:
                keep = int(np.ceil(self._period)) + 2
                self._history = np.concatenate((self._history, h_rest))[-keep:]

    @property
    def _rest_before(self) -> float:
        return float(self._rest_tail[0])

    def _newton_step(self, b: np.ndarray, residual: np.ndarray) -> np.ndarray:
        """Fixed-point step on the iron's remainder, damped by the Newton factor where the iron is
        past its knee: there dH/dB (the anhysteretic slope, which the branches approach in
        saturation) outgrows the airgap's dilution and the plain step would diverge.  The rate
        terms' own slope (the excess field's is steep at slow rates) damps it too."""
        steep = np.abs(b) > self._b_knee
        if self._rate is not None:
            return self._damped(b, residual, self._rate.slope(b), steep)
        if not steep.any():
            return residual
        nu_d = np.full_like(b, self._nu0)
        bs = b[steep]
        an = self.hysteresis.anhysteretic_field
        nu_d[steep] = np.maximum(self._nu0, (an(bs + 1e-3) - an(bs - 1e-3)) / 2e-3)
        return residual / (1.0 + (nu_d - self._nu0) * self._lag.instantaneous_gain * self.iron_length_m)

    def _damped(self, b: np.ndarray, residual: np.ndarray, rate_slope: np.ndarray, steep: np.ndarray) -> np.ndarray:
        """The Newton-damped step with the rate terms' slope added to the iron's beyond the knee."""
        extra = rate_slope.copy()
        if steep.any():
            an = self.hysteresis.anhysteretic_field
            bs = b[steep]
            extra[steep] += np.maximum(0.0, (an(bs + 1e-3) - an(bs - 1e-3)) / 2e-3 - self._nu0)
        return residual / (1.0 + extra * self._lag.instantaneous_gain * self.iron_length_m)

    def _static_field(self, b: np.ndarray):
        """The iron's H for the trajectory b (its temperature's scale and its rate terms included), and
        the state it ends in."""
        if self.hysteresis is None:
            h, state = self._nu0 * b, None
        else:
            h, state = self.hysteresis.field(b, self._h_state, irreversible=self._irreversible,
                                             saturation=self._saturation)
        if self._iron_scale is not None:
            h = h * self._iron_scale
        return (h if self._rate is None else h + self._rate.field(b)), state

    def _pass(self, fc: np.ndarray, fm: np.ndarray, h_rest: np.ndarray):
        """One fixed-point pass on the iron's remainder: (B in the coil leg, the new remainder, the
        iron's state at the block's end, whether the step was below CONVERGED)."""
        x, _ = self._lag.run(np.stack([fc - h_rest * self.iron_length_m, fm]))
        h, h_state = self._static_field(x[0])
        step = self._newton_step(x[0], h - self._nu0 * x[0] - h_rest)
        h_rest = h_rest + step
        return x[0], h_rest, h_state, bool(np.max(np.abs(step)) <= CONVERGED * (np.max(np.abs(h_rest)) + 1.0))

    def _solve_sequential(self, fc: np.ndarray, fm: np.ndarray, current_a: np.ndarray):
        """The block's fixed point where the passes stall (every block they settle below the knee is
        untouched, sample for sample): solved sample by sample (:func:`.ecore_kernel.solve_sequential`:
        each sample's B is bracketed and found, whatever the iron's slope), from the committed
        states, so it does not depend on the passes' iterate nor on where the block begins.

        The passes stall deep in saturation: right after a reversal the branch's dH/dB is the
        reversible one, 1/mu_rev(H) (1e4 A/m per T at 5 kA/m; 1/mu0 in the limit): the loop gain
        (dH/dB - nu0) G L passes 1, and the step damped with the anhysteretic slope does not hold
        it.  (They used to stall below the knee too, where extrema that tie wiped out a loop whose
        tabulated branch missed its turning point by up to 5 A/m: H stepped there, and the passes
        flipped between the two sides; the branches are now closed onto their turning points.)

        One compiled function serves both paths (the numpy step has no vectorised form of a
        causal per-sample solve; without numba it runs as Python, slowly, and only for such
        blocks).  Returns (h_rest, the iron's state at the block's end, max |B|); raises
        SimulationError only if the solve itself fails (never seen; the refusal names the
        operating point)."""
        from . import ecore_kernel as kern

        f64 = np.float64
        fc = np.ascontiguousarray(fc, dtype=f64)
        fm = np.ascontiguousarray(fm, dtype=f64)
        n = fc.size
        coef, _ = self._kernel_constants()
        lag = self._lag
        cold = lag.state is None
        y_start = np.zeros(2) if cold else np.ascontiguousarray(lag.state[0], dtype=f64)
        st = self._h_state
        turns = np.array(st.turns, dtype=f64).reshape(len(st.turns), 2)
        tin, tout = np.empty(turns.shape[0] + n + 2), np.empty(turns.shape[0] + n + 2)
        end, out, h_rest = np.empty(4), np.empty(4), np.empty(n)
        kern.solve_sequential(fc, fm, h_rest, coef, y_start, cold, np.ascontiguousarray(turns[:, 0]),
                              np.ascontiguousarray(turns[:, 1]), np.array([st.b_t, st.h_a_per_m, float(st.direction)]),
                              tin, tout, end, *self._tables(), self._kernel_mode, float(self._nu0),
                              float(self.iron_length_m), self._rest_before, out)
        if out[3] or not np.all(np.isfinite(h_rest)):
            raise self._refusal(float(out[2]), current_a, f"solving sample by sample ({int(out[3])} samples unsolved)")
        m = int(end[3])
        h_state = HysteresisState(float(end[0]), float(end[1]), int(end[2]),
                                  tuple(zip(tin[:m].tolist(), tout[:m].tolist())))
        return h_rest, h_state, float(out[2])

    def _unconverged(self, fc: np.ndarray, fm: np.ndarray, peak_b_t: float, current_a: np.ndarray):
        """What a block whose passes did not converge becomes: solved sample by sample (a Preisach
        iron), as the blocks after it are until the excitation changes (set_period: the passes
        would only stall again, 30 of them a block), or refused (Rayleigh's iron, whose loops the
        compiled solve does not know).  Returns (h_rest, the iron's state at the block's end, max |B|)."""
        if self._sequential_ok:
            self._by_sample = True
            return self._solve_sequential(fc, fm, current_a)
        raise self._refusal(peak_b_t, current_a, f"{MAX_PASSES} passes")

    def expect_current(self, low_a: float, high_a: float) -> None:
        """The range of coil current the new excitation asks for (the rig calls this after
        set_period): if it can take the iron beyond its knee, where the passes stall
        (_solve_sequential says why), every block of the excitation is solved sample by sample,
        however the stream is cut into blocks."""
        fc = self.turns * np.array([low_a, high_a])
        self._by_sample = self._beyond_knee(fc.min(), fc.max(), self.magnet_mmf_a, self.magnet_mmf_a)

    def _beyond_knee(self, fc_low: float, fc_high: float, fm_low: float, fm_high: float) -> bool:
        """Whether coil and magnet MMFs in these ranges can take the iron beyond its knee: B read off
        them with the linear iron at DC (2 % below the B the iron reaches), at the ranges' corners
        (it is affine in both)."""
        b = [self._b_dc[0] * fc + self._b_dc[1] * fm for fc in (fc_low, fc_high) for fm in (fm_low, fm_high)]
        return max(abs(x) for x in b) > self.saturation_knee_t

    def _solve_by_sample(self, fc: np.ndarray, fm: np.ndarray) -> bool:
        """Whether the block is solved sample by sample from the start: in an excitation that takes
        the iron beyond its knee (expect_current), or once a block's passes have stalled, until the
        excitation changes; or when the block's own MMFs reach beyond the knee (a magnet drifting
        with temperature, a rig told nothing of its excitation)."""
        if self._by_sample:
            return True
        if not fc.size:
            return False
        fm_low, fm_high = (self.magnet_mmf_a,) * 2 if self._thermal is None else (float(fm.min()), float(fm.max()))
        return self._beyond_knee(float(fc.min()), float(fc.max()), fm_low, fm_high)

    def _check_range(self, peak_b_t: float, current_a: np.ndarray) -> None:
        """Refuse a block whose iron goes beyond the field range of its material model (checked
        before anything is committed, so the rig may go on with less current)."""
        if peak_b_t > self.max_flux_density_t:
            f_hz = self._preset_frequency_hz if self._period is None else self.fs_hz / self._period
            raise SimulationError(
                f"{self.name} ({self._where}): |B| up to {peak_b_t:.2f} T at {f_hz:.4g} Hz, coil current up to "
                f"{np.max(np.abs(current_a)):.3g} A: saturation beyond the {self.max_flux_density_t:.2f} T to which "
                f"{self._material} is modelled (its field range, h_max = {self.hysteresis.params.h_max_a_per_m:g} "
                "A/m); lower the current")

    def _refusal(self, peak_b_t: float, current_a: np.ndarray, after: str) -> SimulationError:
        """The error for a block whose iron field did not converge: it names the preset's source,
        the operating point, the iron and what was tried (the rig's clock thread passes it on)."""
        f_hz = self._preset_frequency_hz if self._period is None else self.fs_hz / self._period
        knee = (f"beyond the {self.saturation_knee_t:.2f} T knee of {self._material}"
                if peak_b_t > self.saturation_knee_t else f"iron {self._material}")
        return SimulationError(
            f"{self.name} ({self._where}): the iron's field did not converge at {f_hz:.4g} Hz, coil current up to "
            f"{np.max(np.abs(current_a)):.3g} A, |B| up to {peak_b_t:.2f} T ({knee}) after {after}: a limit of the "
            "simulator, not of the bench")

    def step(self, t_s: np.ndarray, current_a: np.ndarray, dcurrent_dt: np.ndarray) -> ActuatorOutput:
        if self._kernel_ok and current_a.size and (jit_enabled() if KERNEL is None else KERNEL):
            return self._step_kernel(t_s, current_a, dcurrent_dt)
        self._iron_scale = None if self._iron_thermal is None else self._iron_thermal.scale(t_s)
        fc = self.turns * current_a
        fm = np.full_like(fc, self.magnet_mmf_a)
        dfm = 0.0
        if self._thermal is not None:
            rate = self._thermal["remanence_tc_per_k"] * self._thermal["kelvin_per_s"]
            fm, dfm = fm * (1.0 + rate * t_s), self.magnet_mmf_a * rate
        # The linear part of the iron and the eddy currents are solved exactly by the recursion;
        # only the iron's nonlinear remainder h(B) - nu0 B is iterated (a small loop gain).
        if self.hysteresis is not None and self._sequential_ok and self._solve_by_sample(fc, fm):
            h_rest, h_state, peak_b = self._solve_sequential(fc, fm, current_a)
        else:
            h_rest, h_state, passes = self._first_guess(fc.size)
            for n_pass in range(1, MAX_PASSES + 1 if self._iterated else 1):
                b, h_rest, h_state, converged = self._pass(fc, fm, h_rest)
                if n_pass >= passes and converged:
                    peak_b = float(np.max(np.abs(b)))
                    break
            else:
                if self._iterated:
                    h_rest, h_state, peak_b = self._unconverged(fc, fm, float(np.max(np.abs(b))), current_a)
        if self.hysteresis is not None:
            self._check_range(peak_b, current_a)
        self._remember(h_rest)
        u = np.stack([fc - h_rest * self.iron_length_m, fm])
        x, lag_state = self._lag.run(u)
        self._h_state, self._lag.state = h_state, lag_state
        if self._rate is not None:
            self._rate.commit(x[0])
        self.iron_flux_density_t = x[0]  # B in the coil leg over this block (reports, tests)
        s = u - self._lag.linear_mmf(x)  # (F_coil, F_magnet) as the airgaps see them

        quad = lambda lam: -0.5 * (lam[0] * s[0] ** 2 + 2 * lam[1] * s[0] * s[1] + lam[2] * s[1] ** 2)  # noqa: E731
        force = quad(self._dlam)
        flux = self._outer @ s
        if self._compliance:
            dz = -force * self._compliance  # the gap closes as the load cell yields
            force = force + quad(self._d2lam) * dz
            flux = flux + (self._douter_dz @ s) * dz
        # d(flux)/dt: the coil's N1 di/dt is analytic; the small iron/eddy part numerical (causal)
        drop = np.stack([fc, fm]) - s
        drop_rate, self._prev_drop = drop_rate_of(drop, self._prev_drop, self.fs_hz)
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

    def _rate_args(self, n: int) -> np.ndarray:
        """The passes kernel's ``rate``: the rate terms and where they stand before the block (none: zeros)."""
        from .ecore_kernel import NO_RATE, rate_terms

        if self._rate is None or not n:
            return NO_RATE
        st = self._rate.state
        b0 = st.b if st is not None else np.nan  # the first block starts at rest: its first sample's B
        return rate_terms(self._rate.excess, self._rate.relaxation, self.fs_hz, b0, st.b_slow if st is not None else np.nan)

    def _tables(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The Preisach iron's tables for the kernel (built once: its ``_inverse`` is cached too)."""
        if self._kernel_tables is None:
            self._kernel_tables = self.hysteresis.kernel_tables()
        return self._kernel_tables

    def _prime_sequential(self, fc: np.ndarray, fm: np.ndarray, current_a: np.ndarray) -> None:
        """Compile (or load from numba's cache) the sample-by-sample solve with the passes, during
        the rig's warm-up: compiled the first time a rig saturates, it would hold a streaming clock
        for 3 s (one sample, nothing committed)."""
        self._primed = True
        try:
            self._solve_sequential(fc[:1], fm[:1], current_a[:1])
        except SimulationError:
            pass

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
        if self.hysteresis is not None and not self._primed:
            self._prime_sequential(fc, fm, current_a)
        if self.hysteresis is None:
            h_rest = np.zeros(n)
        elif self._sequential_ok and self._solve_by_sample(fc, fm):
            h_rest, h_state, peak_b = self._solve_sequential(fc, fm, current_a)
            self._check_range(peak_b, current_a)
            self._remember(h_rest)
            self._h_state = h_state
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
                        self.iron_length_m, out, self._rate_args(fc.size),
                        kern.NO_SCALE if self._iron_thermal is None
                        else np.ascontiguousarray(self._iron_thermal.scale(t_s), dtype=f64))
            if out[0]:
                m = int(end[3])
                h_state = HysteresisState(float(end[0]), float(end[1]), int(end[2]),
                                          tuple(zip(tin[:m].tolist(), tout[:m].tolist())))
                peak_b = float(out[2])
            else:  # as step: solved sample by sample
                h_rest, h_state, peak_b = self._unconverged(fc, fm, float(out[2]), current_a)
            self._check_range(peak_b, current_a)
            self._remember(h_rest)
            self._h_state = h_state
        force, flux, dflux, iron_b = np.empty(n), np.empty(n), np.empty(n), np.empty(n)
        prev = np.full(4, np.nan) if self._prev_drop is None else self._prev_drop.astype(f64)
        lag_end = np.empty(4)
        kern.final_run(fc, fm, h_rest, self.iron_length_m, coef, y_start, cold, nd, float(self.fs_hz),
                       self._dlam, self._d2lam, self._outer, self._douter_dz, float(self._compliance),
                       float(self.turns), np.ascontiguousarray(dcurrent_dt, dtype=f64), float(dfm), prev,
                       force, flux, dflux, iron_b, lag_end)
        lag.state = (lag_end[:2].copy(), lag_end[2:].copy())
        self._prev_drop = prev
        if self._rate is not None:
            self._rate.commit(iron_b)
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
