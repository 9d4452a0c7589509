"""Acquisition imperfections that act on the samples: noise and the ADC."""

from __future__ import annotations

import numpy as np


def add_noise(x: np.ndarray, sigma_white: float, corner_hz: float, fs_hz: float,
              rng: np.random.Generator) -> np.ndarray:
    """White noise of RMS ``sigma_white`` plus flicker (1/f) noise whose PSD equals the white one at
    ``corner_hz``: a real front end's floor, shaped in the frequency domain of this record."""
    n = x.size
    white = rng.standard_normal(n) * sigma_white
    spec = np.fft.rfft(rng.standard_normal(n) * sigma_white)
    f = np.fft.rfftfreq(n, 1 / fs_hz)
    shape = np.zeros(f.size)
    shape[1:] = np.sqrt(corner_hz / f[1:])
    pink = np.fft.irfft(spec * shape, n)
    return x + white + pink


def quantise(x: np.ndarray, full_scale: float, bits: int) -> np.ndarray:
    """A bipolar ADC of +-full_scale: mid-tread rounding to its LSB, clipped at the rails."""
    lsb = 2 * full_scale / 2**bits
    return np.clip(np.round(x / lsb), -(2 ** (bits - 1)), 2 ** (bits - 1) - 1) * lsb
