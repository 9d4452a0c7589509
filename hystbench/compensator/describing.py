"""A describing-function model of the iron: the iron's and the eddy currents' share of the coil
current as one complex gain per harmonic, smooth in frequency and amplitude.

    I_k = (1 + G(k f, A)) J_k   (k >= 1),   I_0 = J_0 + delta,   F = k0 + k1 j + k2 j^2

with J_k the harmonics of j (the current the airgaps see, from :mod:`.calibration`) and A the
amplitude of j's fundamental.  G is the iron's complex reluctance relative to the gap's -- the
paper's complex-impedance picture (Sec. II B: "the elliptic behavior of minor loops ... translated
to a complex impedance model") -- with the amplitude dependence Rayleigh's law gives and the
eddy currents' growth with frequency:

    Re G = a0 + a1 A + a2 A^2 + a3 (2 pi f)^2,      Im G = b0 + b1 A + b2 A^2 + 2 pi f tau.

(a3: the eddy currents' second-order term, -(omega tau)^2 of a first-order lag: 4e-4 of the
force at 480 Hz, enough to matter at the 1e-3 the accuracy asks.)

Linear in its parameters, so fitted by weighted least squares on the fundamentals of a sweep, with
the covariance for free.  It describes loops that are ellipses exactly (any loss angle, any
amplitude dependence of it); it cannot describe a loop's shape beyond its fundamental (the pointed
tips of a Preisach iron), which is why it competes with :mod:`.hysteresis_eddy` rather than
replacing it (:mod:`.identify` chooses by held-out error).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

from .errors import CompensatorError
from .lsq import linear_fit
from .periodic import harmonics
from .seen_current import SeenCurrentModel
from .static import StaticLaw

__all__ = ["DescribingFunctionModel", "fit_describing_function", "RE_TERMS", "IM_TERMS"]

RE_TERMS = ("1", "A", "A^2", "(2 pi f)^2")
IM_TERMS = ("1", "A", "A^2", "2 pi f (tau, s)")
_AMPLITUDE_PASSES = 6  # the amplitude of j changes G by a few 1e-3: a few passes settle it


def _amplitude(spec: np.ndarray, n: int) -> float:
    return 2.0 * float(np.abs(spec[1])) / n


@dataclass
class DescribingFunctionModel(SeenCurrentModel):
    """See the module docstring; ``re``/``im`` are the coefficients of :data:`RE_TERMS`/:data:`IM_TERMS`."""

    law: StaticLaw
    re: tuple[float, ...]
    im: tuple[float, ...]
    offset_a: float = 0.0
    report: dict = field(default_factory=dict)
    kind = "best"
    name = "describing_function"

    def gain(self, frequency_hz: np.ndarray | float, amplitude_a: float) -> np.ndarray:
        """G(f, A) (complex, per frequency)."""
        f = np.asarray(frequency_hz, float)
        a = float(amplitude_a)
        re = self.re[0] + self.re[1] * a + self.re[2] * a * a + self.re[3] * (2 * np.pi * f) ** 2
        im = self.im[0] + self.im[1] * a + self.im[2] * a * a + 2 * np.pi * f * self.im[3]
        return re + 1j * im

    def _factor(self, n: int, frequency_hz: float, amplitude_a: float) -> np.ndarray:
        k = harmonics(n)
        g = 1.0 + self.gain(k * frequency_hz, amplitude_a)
        g[0] = 1.0
        return g

    def current_for(self, j_a: np.ndarray, frequency_hz: float) -> np.ndarray:
        """The coil current (one period) that makes the airgaps see ``j_a``."""
        j = np.asarray(j_a, float)
        spec = np.fft.rfft(j)
        out = np.fft.irfft(spec * self._factor(j.size, frequency_hz, _amplitude(spec, j.size)), j.size)
        return out + self.offset_a

    def effective_current(self, current_a: np.ndarray, frequency_hz: float) -> np.ndarray:
        """j for one period of the coil current: the gain depends on j's amplitude, so a few passes."""
        i = np.asarray(current_a, float)
        spec = np.fft.rfft(i - self.offset_a)
        amp = _amplitude(spec, i.size)
        for _ in range(_AMPLITUDE_PASSES):
            js = spec / self._factor(i.size, frequency_hz, amp)
            amp = _amplitude(js, i.size)
        return np.fft.irfft(js, i.size)

    def to_dict(self) -> dict:
        return {"kind": self.kind, "name": self.name, "law": self.law.to_dict(),
                "re_terms": list(RE_TERMS), "re": list(self.re), "im_terms": list(IM_TERMS), "im": list(self.im),
                "offset_A": self.offset_a, "report": self.report}

    @classmethod
    def from_dict(cls, d: dict) -> "DescribingFunctionModel":
        re, im = tuple(map(float, d["re"])), tuple(map(float, d["im"]))
        if len(re) != len(RE_TERMS) or len(im) != len(IM_TERMS):
            raise CompensatorError(f"describing_function model: expected {len(RE_TERMS)} + {len(IM_TERMS)} "
                                   f"coefficients, got {len(re)} + {len(im)}")
        return cls(StaticLaw.from_dict(d["law"]), re, im, float(d.get("offset_A", 0.0)), dict(d.get("report", {})))


def fit_describing_function(js: Sequence[np.ndarray], currents: Sequence[np.ndarray], freqs_hz: Sequence[float],
                            law: StaticLaw, names: Sequence[str]) -> DescribingFunctionModel:
    """G from the fundamentals of a sweep (j and i per recording, one period each, same length):
    (I_1 - J_1) / J_1 = G(f, A), weighted by the loop's amplitude (a small loop's gain is noisy and
    matters little to the force)."""
    if len(js) < 3:
        raise CompensatorError(f"the describing-function model needs at least 3 recordings, got {len(js)}")
    rows_re, rows_im, y_re, y_im, w = [], [], [], [], []
    for j, i, f in zip(js, currents, freqs_hz):
        jspec, ispec = np.fft.rfft(j), np.fft.rfft(i)
        amp = _amplitude(jspec, j.size)
        g = (ispec[1] - jspec[1]) / jspec[1]
        rows_re.append([1.0, amp, amp * amp, (2 * np.pi * f) ** 2])
        rows_im.append([1.0, amp, amp * amp, 2 * np.pi * f])
        y_re.append(g.real)
        y_im.append(g.imag)
        w.append(amp)
    w = np.asarray(w) / max(w)
    fits = [linear_fit(np.asarray(rows) * w[:, None], np.asarray(y) * w)
            for rows, y in ((rows_re, y_re), (rows_im, y_im))]
    (re, re_se, re_res), (im, im_se, im_res) = ((f.coef, f.se, f.resid) for f in fits)
    offset = float(np.mean([np.mean(i) - np.mean(j) for j, i in zip(js, currents)]))
    report = {"re": {t: [float(c), float(s)] for t, c, s in zip(RE_TERMS, re, re_se)},
              "im": {t: [float(c), float(s)] for t, c, s in zip(IM_TERMS, im, im_se)},
              "gain_residual": {n: [float(a), float(b)] for n, a, b in zip(names, re_res / w, im_res / w)}}
    return DescribingFunctionModel(law, tuple(map(float, re)), tuple(map(float, im)), offset, report)
