"""The frame mode search (analysis/diagnosis/search.py) finds a mode of a bench not ours from the force
harmonics alone: its frequency between two measured points, its damping, and the side its gain steps."""

from __future__ import annotations

import numpy as np
from scipy import signal

from hystbench.analysis.diagnosis.fit import Problem
from hystbench.analysis.diagnosis.search import frame_mode_search
from hystbench.analysis.diagnosis.vector import CHANNELS, Layout

FORCE = CHANNELS.index("force_N")


def _mode(f_hz: np.ndarray, f_mode: float, zeta: float, depth: float, f_zero: float) -> np.ndarray:
    """A two-mass frame mode's response, from its poles and zeros (scipy.signal.freqs, not the search's
    closed form): unity DC gain."""
    wp, wz = 2 * np.pi * f_mode, 2 * np.pi * f_zero
    b = [1 / wz**2, 2 * zeta * (1 + depth) / wz, 1.0]
    a = [1 / wp**2, 2 * zeta / wp, 1.0]
    return signal.freqs(b, a, worN=2 * np.pi * f_hz)[1]


def test_a_mode_between_the_voice_coils_points_is_found():
    freqs = np.array([40.0, 80.0, 160.0, 320.0, 640.0, 1000.0, 1500.0, 2000.0, 3000.0])  # the voice coil's day
    K = 3
    rec = np.repeat(np.arange(freqs.size), 2 * K)
    harm = np.tile(np.repeat(np.arange(1, K + 1), 2), freqs.size)
    part = np.tile([0, 1], freqs.size * K)
    F = 2.0 / harm.astype(float) * np.exp(-0.3j * harm)  # the model's force harmonics (any)
    truth = F * _mode(harm * freqs[rec], 1175.0, 0.015, 0.3, 1175.0 * 1.01)
    vec = lambda z: np.where(part == 0, z.real, z.imag)  # noqa: E731
    se = np.full(rec.size, 1e-4)
    layout = Layout(rec, np.full(rec.size, FORCE), harm, part, se, np.full(rec.size, 2.0))
    rng = np.random.default_rng(2)
    d = vec(truth) + rng.normal(scale=1e-4, size=rec.size)
    problem = Problem(d, se, np.arange(rec.size), lambda r: [], layout, se, np.zeros(0, int))
    found = frame_mode_search(problem, vec(F), [], freqs)
    assert abs(found["frequency_hz"] / 1175.0 - 1) < 0.03, found
    assert found["split"] > 0, found  # the anti-resonance above the resonance
    assert found["depth"] > 0, found
