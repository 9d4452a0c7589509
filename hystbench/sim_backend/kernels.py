"""Compiled (numba) kernels of the simulated rig's signal generator and measurement chain.

Each kernel is the per-sample loop of a numpy expression in ``rig.py`` or ``measurement.py``, with
the same floating-point operations in the same order, so it gives the same samples (the numpy code
stays beside it as the reference and the fallback).  Numpy spends its time here on temporaries and
on a transcendental pair per sample; one loop over the block does not (issue 14, CPU ms per 10 000
samples: the sine 0.20 -> 0.017, the force filter 0.086 -> 0.035, noise + ADC 0.025 -> 0.005 a channel,
the noise draws 0.094 -> 0.039 a channel).

Imported only when ``hystbench.jit.enabled()`` (so importing the rig never imports numba); callers
pass C-contiguous float64 arrays, so one specialisation serves every call.
"""

from __future__ import annotations

import math

import numpy as np

from ..jit import njit

__all__ = ["sine_and_rate", "sosfilt", "standard_normal", "noise_adc", "ANGLE_BLOCK"]

#: Samples per exact angle in :func:`sine_and_rate`: the table costs 2 x ANGLE_BLOCK sin/cos a call,
#: each exact angle 2, the samples in between one complex multiply.
ANGLE_BLOCK = 64


@njit(cache=True, nogil=True)
def sine_and_rate(c0: float, step: float, offset: float, amp: float, amp_w: float,
                  out_i: np.ndarray, out_di: np.ndarray) -> None:
    """``out_i = offset + amp sin(2 pi (c0 + step k))``, ``out_di = amp_w cos(...)``, k = 0..n-1.

    By angle addition: sin/cos of every ANGLE_BLOCK-th phase (computed as numpy computes the phase,
    ``c0 + step * k``) times a table of sin/cos(2 pi step j).  The error is a few ulp of the result,
    inside the rounding the phase ``2 pi (c0 + step k)`` already carries."""
    n = out_i.size
    tp = 2.0 * np.pi
    blk = ANGLE_BLOCK
    sb = np.empty(blk)
    cb = np.empty(blk)
    for j in range(blk):
        sb[j] = math.sin(tp * (step * j))
        cb[j] = math.cos(tp * (step * j))
    for k0 in range(0, n, blk):
        th = tp * (c0 + step * k0)
        sa = math.sin(th)
        ca = math.cos(th)
        for j in range(min(blk, n - k0)):
            out_i[k0 + j] = offset + amp * (sa * cb[j] + ca * sb[j])
            out_di[k0 + j] = amp_w * (ca * cb[j] - sa * sb[j])


@njit(cache=True, nogil=True)
def sosfilt(sos: np.ndarray, zi: np.ndarray, x: np.ndarray, y: np.ndarray) -> None:
    """``y[:], zi[:] = scipy.signal.sosfilt(sos, x, zi=zi)`` (``y`` may be ``x``): the transposed
    direct form II recursion scipy runs, with each section's operations in scipy's order (so the
    numbers are scipy's).  Sections go over the block two at a time with their state in locals: one
    section's recursion is latency-bound, and the second runs in the first one's shadow (0.066 ->
    0.034 ms per 10 000 samples for the force filter's two sections)."""
    s = 0
    n_sections = sos.shape[0]
    src = x
    while s < n_sections:
        b0, b1, b2, a1, a2 = sos[s, 0], sos[s, 1], sos[s, 2], sos[s, 4], sos[s, 5]
        z0, z1 = zi[s, 0], zi[s, 1]
        if s + 1 < n_sections:
            c0, c1, c2, d1, d2 = sos[s + 1, 0], sos[s + 1, 1], sos[s + 1, 2], sos[s + 1, 4], sos[s + 1, 5]
            w0, w1 = zi[s + 1, 0], zi[s + 1, 1]
            for k in range(y.size):
                xk = src[k]
                v = b0 * xk + z0
                z0 = b1 * xk - a1 * v + z1
                z1 = b2 * xk - a2 * v
                u = c0 * v + w0
                w0 = c1 * v - d1 * u + w1
                w1 = c2 * v - d2 * u
                y[k] = u
            zi[s + 1, 0] = w0
            zi[s + 1, 1] = w1
        else:
            for k in range(y.size):
                xk = src[k]
                v = b0 * xk + z0
                z0 = b1 * xk - a1 * v + z1
                z1 = b2 * xk - a2 * v
                y[k] = v
        zi[s, 0] = z0
        zi[s, 1] = z1
        src = y
        s += 2


@njit(cache=True, nogil=True)
def standard_normal(rng: np.random.Generator, out: np.ndarray) -> None:
    """``out[:] = rng.standard_normal(out.size)``: numba's Generator runs numpy's ziggurat on the
    same bit generator, so the draws and the generator's state after them are numpy's, at 4 ns a
    draw instead of 9 (the noise was half of the rig's time: 5 channels x 10 000 draws a block)."""
    for k in range(out.size):
        out[k] = rng.standard_normal()


@njit(cache=True, nogil=True)
def noise_adc(x: np.ndarray, sigma: float, draws: np.ndarray, noisy: bool, full_scale: float, lsb: float,
              quantise: bool, out: np.ndarray) -> bool:
    """``out = x + sigma * draws`` (when ``noisy``), then (when ``quantise``) the ADC:
    ``rint(clip(v, -fs, fs - lsb) / lsb) * lsb``; True when any |v| > fs (the block's CLIP flag).
    NaN passes through as ``np.clip`` lets it."""
    clipped = False
    hi = full_scale - lsb
    for k in range(x.size):
        v = x[k]
        if noisy:
            v = v + sigma * draws[k]
        if quantise:
            if abs(v) > full_scale:
                clipped = True
            if v < -full_scale:
                v = -full_scale
            elif v > hi:
                v = hi
            v = np.rint(v / lsb) * lsb
        out[k] = v
    return clipped
