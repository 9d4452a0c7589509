"""The measuring side of the bench: what happens to each true signal before it is a sample.

Force: load cell + frame + charge amplifier (and, when switched on, frame modes, the charge
amplifier's high-pass, its offset drift, mains pick-up).  Flux: the integrator (ideal: AC only;
lossy when ``integrator_leak`` is on).  Every channel: sampling skew, noise, ADC rounding/clipping.
"""

from __future__ import annotations

import dataclasses
import math
from types import ModuleType
from typing import Any, Mapping

import numpy as np
from scipy import signal

from .. import jit
from ..blocks import BlockFlags
from ..physics import presets as physics_presets
from ..physics.instrument import InstrumentModel, bilinear_sos

__all__ = ["MeasurementChain", "FractionalDelay", "instrument_from_preset", "noise_adc_reference", "KERNEL"]

_NO_DRAWS = np.empty(0)  # the noise kernel's draws when the noise is off (one array type, one specialisation)
_NOISE_KEYS = {"current_A": "current_a", "force_N": "force_n", "flux_Wb": "flux_wb",
               "sense_V": "sense_v", "command_V": "command_v"}


def instrument_from_preset(preset: Mapping[str, Any], effects: Mapping[str, Mapping[str, Any]] | None = None
                           ) -> InstrumentModel:
    """The instrument model of a preset; with ``effects``, the frame modes and high-pass that are on."""
    effects = effects or {}
    modes: tuple = ()
    if "frame_resonance" in effects:
        fr = effects["frame_resonance"]
        zeta = float(fr["zeta"])
        split = 1.0 + float(fr.get("split", 0.0))
        modes = tuple((float(f), zeta, zeta * (1.0 + float(fr["depth"])), float(f) * split)
                      for f in fr["frequencies_hz"])
    hp = effects.get("charge_amp_highpass")
    return dataclasses.replace(
        physics_presets.instrument(preset), frame_modes=modes,
        highpass_time_constant_s=None if hp is None else float(hp["time_constant_s"]))


class FractionalDelay:
    """Delay by a non-integer number of samples, carrying the history across blocks: the whole samples
    from the history, the fraction by a first-order Thiran allpass (Laakso et al., "Splitting the unit
    delay", 1996), with D in [1, 2) where a whole sample is there to take (its most accurate range).

    An allpass keeps every frequency's amplitude, as a late sample clock does; the linear interpolation
    this used before lost p(1 - p)(wT)^2/2 of it (8e-4 at 3 kHz for 0.5 us at 100 kHz), an amplitude
    no skew has, which a bench written from the physics does not show.  The phase delay is D to
    O((wT)^2): 3e-3 of it at 3 kHz."""

    def __init__(self, delay_samples: float) -> None:
        if delay_samples < 0:
            raise ValueError(f"delay_samples must be >= 0, got {delay_samples}")
        whole = int(math.floor(delay_samples))
        frac = delay_samples - whole
        if frac > 0.0 and whole >= 1:
            whole, frac = whole - 1, frac + 1.0
        self.whole, self.frac = whole, frac
        a = (1.0 - frac) / (1.0 + frac)
        self._ba = (np.array([a, 1.0]), np.array([1.0, a])) if frac > 0.0 else None
        self._history: np.ndarray | None = None
        self._zi: np.ndarray | None = None

    def __call__(self, x: np.ndarray) -> np.ndarray:
        x = np.asarray(x, dtype=float)
        if self._history is None:
            self._history = np.full(self.whole, x[0])
        ext = np.concatenate((self._history, x))
        y, self._history = ext[:x.size], ext[x.size:]
        if self._ba is None:
            return y
        if self._zi is None:  # in steady state for the first value, as the instrument's filters start
            self._zi = signal.lfilter_zi(*self._ba) * y[0]
        y, self._zi = signal.lfilter(*self._ba, y, zi=self._zi)
        return y


#: None: the compiled kernels run when ``jit.enabled()``; a test sets True or False to run one path.
KERNEL: bool | None = None


def _kernels() -> ModuleType | None:
    """``hystbench.sim_backend.kernels`` when compiled kernels run (asked at each call, so a test
    can set ``KERNEL`` and run both paths in one process), else None: the numpy path."""
    if not (jit.enabled() if KERNEL is None else KERNEL):
        return None
    from . import kernels

    return kernels


class _Sos:
    """A stateful sosfilt that starts in steady state for its first input value.  ``sosfilt`` is
    the reference; the compiled kernel runs the same recursion on the same state."""

    def __init__(self, sos: np.ndarray) -> None:
        self.sos = np.ascontiguousarray(sos, dtype=np.float64)
        self.zi: np.ndarray | None = None

    def __call__(self, x: np.ndarray) -> np.ndarray:
        if self.zi is None:
            self.zi = signal.sosfilt_zi(self.sos) * x[0]
        kernels = _kernels()
        if kernels is None:
            y, self.zi = signal.sosfilt(self.sos, x, zi=self.zi)
            return y
        x = np.ascontiguousarray(x, dtype=np.float64)
        y = np.empty(x.size)
        self.zi = np.ascontiguousarray(self.zi, dtype=np.float64)
        kernels.sosfilt(self.sos, self.zi, x, y)
        return y


def noise_adc_reference(x: np.ndarray, sigma: float | None, draws: np.ndarray | None,
                        full_scale: float | None, lsb: float) -> tuple[np.ndarray, bool]:
    """``x + sigma * draws`` (with noise), then the ADC (with ``full_scale``): clip to one LSB below
    full scale, round to the LSB; and whether any sample was beyond full scale (the CLIP flag)."""
    clipped = False
    if sigma is not None:
        x = x + sigma * draws
    if full_scale is not None:
        if np.any(np.abs(x) > full_scale):
            clipped = True
        x = np.round(np.clip(x, -full_scale, full_scale - lsb) / lsb) * lsb
    return x, clipped


class MeasurementChain:
    """Each true signal through its instrument, the sample clock and the ADC (module docstring):
    what the rig's channels hold is what a real bench would have measured."""

    def __init__(self, preset: Mapping[str, Any], effects: Mapping[str, Mapping[str, Any]],
                 fs_hz: float, channels: list[str], seed: int) -> None:
        self.fs_hz = fs_hz
        self.channels = channels
        self.effects = effects
        self._force_filter = None
        if "force_N" in channels:  # a toroid has no load cell
            instrument = instrument_from_preset(preset, effects)
            sos = instrument.sos(fs_hz, core="instrument_filter" in effects)
            self._force_filter = _Sos(sos) if len(sos) else None
        leak = effects.get("integrator_leak")
        self._flux_filter = None
        if leak is not None:
            tau = float(leak["time_constant_s"])
            self._flux_filter = _Sos(bilinear_sos(np.array([tau, 0.0]), np.array([tau, 1.0]), fs_hz))
        skew = effects.get("channel_skew", {})
        self._skew = {ch: FractionalDelay(float(skew[ch]) * fs_hz) for ch in channels
                      if float(skew.get(ch, 0.0)) > 0.0}
        seq = np.random.SeedSequence(seed)
        self._rng = {ch: np.random.default_rng(s) for ch, s in zip(channels, seq.spawn(len(channels)))}
        mains_rng = np.random.default_rng(seq.spawn(1)[0])
        self._mains_phase = mains_rng.uniform(0, 2 * np.pi, size=2)
        noise, adc = effects.get("sensor_noise"), effects.get("adc_quantisation")
        #: per channel (noise sigma or None, ADC full scale or None, LSB): looked up once, not per block
        self._noise_adc = {ch: (None if noise is None else float(noise[_NOISE_KEYS[ch]]),
                                None if adc is None else float(adc[_NOISE_KEYS[ch]]),
                                1.0 if adc is None else 2.0 * float(adc[_NOISE_KEYS[ch]]) / 2 ** int(adc["bits"]))
                           for ch in channels}

    def _mains(self, t_s: np.ndarray, amplitude: float, which: int) -> np.ndarray:
        m = self.effects["mains_pickup"]
        w = 2 * np.pi * float(m["frequency_hz"])
        ph = self._mains_phase[which]
        return amplitude * (np.sin(w * t_s + ph) + float(m["third_harmonic"]) * np.sin(3 * (w * t_s + ph)))

    def measure(self, t_s: np.ndarray, truth: Mapping[str, np.ndarray]) -> tuple[dict[str, np.ndarray], BlockFlags]:
        """Samples as the ADC delivers them, from the true signals of one block."""
        out: dict[str, np.ndarray] = {}
        flags = BlockFlags.NONE
        e = self.effects
        kernels = _kernels() if "sensor_noise" in e or "adc_quantisation" in e else None
        for ch in self.channels:
            x = np.asarray(truth[ch], dtype=float)
            if ch == "force_N":
                if self._force_filter is not None:
                    x = self._force_filter(x)
                if "force_offset_drift" in e:
                    x = x + float(e["force_offset_drift"]["offset_n"]) + float(e["force_offset_drift"]["drift_n_per_s"]) * t_s
                if "mains_pickup" in e:
                    x = x + self._mains(t_s, float(e["mains_pickup"]["force_n"]), 0)
            elif ch == "flux_Wb" and self._flux_filter is not None:
                x = self._flux_filter(x)
            elif ch == "sense_V" and "mains_pickup" in e:
                x = x + self._mains(t_s, float(e["mains_pickup"]["sense_v"]), 1)
            if ch in self._skew:
                x = self._skew[ch](x)
            sigma, full_scale, lsb = self._noise_adc[ch]
            # each channel its own generator: the draws never depend on the path or the cut
            draws = None
            if sigma is not None and kernels is not None:
                draws = np.empty(x.size)
                kernels.standard_normal(self._rng[ch], draws)
            elif sigma is not None:
                draws = self._rng[ch].standard_normal(x.size)
            if kernels is not None:
                x = np.ascontiguousarray(x, dtype=np.float64)
                y = np.empty(x.size)
                clipped = kernels.noise_adc(x, 0.0 if sigma is None else sigma, _NO_DRAWS if draws is None else draws,
                                            sigma is not None, 1.0 if full_scale is None else full_scale, lsb,
                                            full_scale is not None, y)
                x = y
            else:
                x, clipped = noise_adc_reference(x, sigma, draws, full_scale, lsb)
            if clipped:
                flags |= BlockFlags.CLIP
            out[ch] = x
        return out, flags
