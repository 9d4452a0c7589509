"""Force-measurement instrument: load cell + frame (mechanical 2nd-order low-pass) in cascade with the
charge amplifier's 2nd-order low-pass (paper Sec. IV C, Figs. 8-9), plus the optional effects the
paper mentions but leaves out of its model: small frame resonances (Fig. 7c) and the piezo/charge
amplifier high-pass (a load cell cannot hold a static charge).

Continuous-time models give the phase the method must remove; ``sos(fs)`` gives the same response
sampled, for the simulator.  The two low-passes are sampled together by a first-order hold with the
hold's own loss undone (:func:`hold_sos`), which keeps the continuous response to O((fT)^4) below the
load cell's resonance (when that lies below fs/2).  A real bench is continuous: the bilinear transform
this used before, pre-warped at the resonance, bent the response by 0.6 % at 3 kHz (0.3 % at 2 kHz) on
a 100 kHz clock, a misfit of several noise floors that the diagnosis took for a frame mode on every
day of a bench that was not this simulator.  Frame modes and the high-pass stay bilinear, pre-warped
at their mode: a mode's pair is near unity away from it, and the high-pass acts near DC, where the
warp vanishes.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike
from scipy import signal

__all__ = ["InstrumentModel", "second_order_lowpass", "resonance_pair", "bilinear_sos", "hold_sos"]


def second_order_lowpass(corner_hz: float, zeta: float) -> tuple[np.ndarray, np.ndarray]:
    """w^2 / (s^2 + 2 zeta w s + w^2), unity gain at DC, w = 2 pi ``corner_hz``."""
    w = 2 * np.pi * corner_hz
    return np.array([w * w]), np.array([1.0, 2 * zeta * w, w * w])


def resonance_pair(resonance_hz: float, zeta_pole: float, zeta_zero: float,
                   f_zero_hz: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """A small mode at f = ``resonance_hz``: unity gain below f, gain zeta_zero/zeta_pole at f, a local
    phase wiggle.  With its anti-resonance at ``f_zero_hz`` (a frame's two masses: the zero apart from
    the pole) the gain steps by (f/f_zero)^2 across the mode and its phase swings one way below it,
    the other above."""
    w = 2 * np.pi * resonance_hz
    wz = w if f_zero_hz is None else 2 * np.pi * f_zero_hz
    r2 = (w / wz) ** 2  # unity DC gain: (s^2 / wz^2 + 2 zeta_z s / wz + 1) / (s^2 / w^2 + 2 zeta_p s / w + 1)
    return np.array([r2, 2 * zeta_zero * w * w / wz, w * w]), np.array([1.0, 2 * zeta_pole * w, w * w])


def bilinear_sos(b: np.ndarray, a: np.ndarray, fs_hz: float, prewarp_hz: float | None = None) -> np.ndarray:
    """Bilinear transform of one section to an SOS row, optionally pre-warped at ``prewarp_hz``.

    A pre-warp frequency at or above fs/2 has no digital frequency to match (tan diverges there):
    the section is then transformed without pre-warping, which keeps the low-frequency response
    (a load cell's resonance above the Nyquist frequency of a slow recording is still a lag)."""
    fs_eff = fs_hz
    if prewarp_hz is not None and prewarp_hz < fs_hz / 2:
        wp = 2 * np.pi * prewarp_hz
        fs_eff = wp / (2 * np.tan(wp / (2 * fs_hz)))
    bz, az = signal.bilinear(b, a, fs=fs_eff)
    return signal.tf2sos(bz, az)


def hold_sos(b: np.ndarray, a: np.ndarray, fs_hz: float) -> np.ndarray:
    """A section sampled by first-order hold (its response to the samples joined by straight lines),
    with the hold's loss undone, as SOS rows.

    Straight lines pass a tone at sinc^2(f/fs) = 1 - (2 pi f/fs)^2/12 + ...; sampling H(s) (1 - s^2 T^2/12)
    instead of H(s) undoes that to fourth order, with no warp of the frequency axis (the bilinear
    transform's is second order, and grows toward a sharp resonance).  The section needs a relative
    degree of two or more, room for the correction's two zeros; a low-pass's images at fs -+ f, which a
    hold lets through, are then attenuated before they alias back."""
    t = 1.0 / fs_hz
    b = np.polymul(np.atleast_1d(np.asarray(b, float)), [-t * t / 12.0, 0.0, 1.0])
    a = np.atleast_1d(np.asarray(a, float))
    if b.size > a.size:
        raise ValueError("hold_sos: a section of relative degree two or more is needed (a low-pass)")
    bz, az, _ = signal.cont2discrete((b, a), t, method="foh")
    return signal.tf2sos(np.ravel(bz), np.ravel(az))


@dataclass(frozen=True)
class InstrumentModel:
    """H_instr(s) = H_mech(s) * H_LPF(s) [* frame modes] [* charge-amplifier high-pass]."""

    fn_hz: float = 4450.0
    zeta_n: float = 0.012
    f0_hz: float = 31000.0
    zeta_0: float = 1.0
    frame_modes: tuple[tuple[float, ...], ...] = field(default=())  # (f, zeta_p, zeta_z[, f_zero])
    highpass_time_constant_s: float | None = None

    def sections(self, *, core: bool = True) -> list[tuple[np.ndarray, np.ndarray, float | None]]:
        """(b, a, prewarp frequency) of every continuous-time section; ``core=False`` leaves out the
        two low-passes of the paper's model (the simulator's ``instrument_filter`` switched off)."""
        out = []
        if core:
            out += [(*second_order_lowpass(self.fn_hz, self.zeta_n), self.fn_hz),
                    (*second_order_lowpass(self.f0_hz, self.zeta_0), None)]
        out += [(*resonance_pair(*mode), mode[0]) for mode in self.frame_modes]
        if self.highpass_time_constant_s is not None:
            tau = self.highpass_time_constant_s
            out.append((np.array([tau, 0.0]), np.array([tau, 1.0]), None))
        return out

    def frequency_response(self, frequency_hz: ArrayLike) -> np.ndarray:
        """Complex H(j 2 pi f) of the continuous model."""
        f = np.asarray(frequency_hz, dtype=float)
        w = 2 * np.pi * np.atleast_1d(f)
        h = np.ones_like(w, dtype=complex)
        for b, a, _ in self.sections():
            h *= signal.freqs(b, a, worN=w)[1]
        return h.reshape(f.shape)

    def phase_deg(self, frequency_hz: ArrayLike) -> np.ndarray:
        """Phase of H in degrees (negative: the measured force lags the actuator's force)."""
        f = np.asarray(frequency_hz, dtype=float)
        h = np.atleast_1d(self.frequency_response(f))
        return np.degrees(np.unwrap(np.angle(h))).reshape(f.shape)

    def delay_s(self, frequency_hz: ArrayLike) -> np.ndarray:
        """Equivalent time delay -phase/omega (positive: the measured force is late)."""
        f = np.asarray(frequency_hz, dtype=float)
        return -np.radians(self.phase_deg(f)) / (2 * np.pi * f)

    def sos(self, fs_hz: float, *, core: bool = True) -> np.ndarray:
        """Second-order sections of the sampled model at ``fs_hz`` (for scipy.signal.sosfilt; module
        docstring); no rows when nothing is left (``core=False`` and no mode or high-pass)."""
        sections = self.sections(core=core)
        rows = []
        # the two low-passes as one fourth-order pair; a load cell above the Nyquist frequency stays
        # bilinear (a hold would fold its images back through the resonance)
        if core and self.fn_hz < fs_hz / 2:
            (b1, a1, _), (b2, a2, _) = sections[:2]
            rows.append(hold_sos(np.polymul(b1, b2), np.polymul(a1, a2), fs_hz))
            sections = sections[2:]
        rows += [bilinear_sos(b, a, fs_hz, pw) for b, a, pw in sections]
        return np.vstack(rows) if rows else np.empty((0, 6))
