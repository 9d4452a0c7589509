"""Where to look before simulating: a frame mode's frequency and damping, searched on the calibrated fit.

A frame mode of a bench not ours has its own frequency and damping, and a lightly damped mode is
sharp: a grid of replays half an octave apart misses it by more than its width.  Its effect on the
force is known in closed form, though: the mode is a filter on the force channel,
``H(s) = (s^2 + 2 zeta (1 + depth) w s + w^2) / (s^2 + 2 zeta w s + w^2)``, so each force harmonic of
the calibrated baseline moves by ``F_k (H(i k omega) - 1)``, which is ``depth`` times a shape that
depends on the frequency and the damping only.  Every (frequency, damping) pair of a fine grid is
scored at once by the share of the calibrated residual its shape explains (projected off the
calibration's columns); the best is then simulated on the rig like any candidate.
"""

from __future__ import annotations

import numpy as np

from .columns import FRAME_BAND_HZ
from .fit import Column, Problem
from .vector import CHANNELS

__all__ = ["frame_mode_search", "FRAME_SEARCH_HZ", "FRAME_SEARCH_ZETA"]

#: Frame mode frequencies searched (Hz): 2 % apart, from the E-cores' low harmonics to beyond the
#: voice coil's highest point.
FRAME_SEARCH_HZ = np.geomspace(*FRAME_BAND_HZ, 167)
#: A mode this close (relative) to the load cell's own resonance is not searched.
LOAD_CELL_BAND = 0.2
#: Damping ratios searched: a stiff bolted frame to a soft mount.
FRAME_SEARCH_ZETA = (0.005, 0.01, 0.02, 0.04)


def frame_mode_search(problem: Problem, m0: np.ndarray, calibration_columns: list[Column],
                      frequency_hz: np.ndarray, load_cell_hz: float | None = None) -> dict[str, float]:
    """The frame mode whose shape explains most of the calibrated residual: its frequency (Hz), damping
    ratio, and the depth and split (linearised amplitudes) that fit it; ``frequency_hz``: each
    record's fundamental.  Only modes up to the highest excitation frequency are searched, and none within LOAD_CELL_BAND of ``load_cell_hz`` (the calibrated load cell's
    resonance) are not searched: a mode there reshapes the load cell's own resonance, which is the
    instrument's calibration (and its misfit), not a frame."""
    layout, rows = problem.layout, problem.rows
    force = rows[(rows < layout.size)]
    force = force[(layout.channel[force] == CHANNELS.index("force_N")) & (layout.harmonic[force] > 0)]
    if not force.size:
        return {"frequency_hz": float(FRAME_SEARCH_HZ[0]), "zeta": FRAME_SEARCH_ZETA[0], "depth": 0.0, "split": 0.0}
    # the model's complex force harmonic at each force row, and the row's part
    rec, k, part = layout.record[force], layout.harmonic[force], layout.part[force]
    key = rec * 1000 + k
    complex_of: dict[int, complex] = {}
    for i, kk, p in zip(force, key, part):
        complex_of[kk] = complex_of.get(kk, 0j) + (m0[i] if p == 0 else 1j * m0[i])
    F = np.array([complex_of[kk] for kk in key])[:, None]
    s = 2j * np.pi * k * frequency_hz[rec]
    s = s[:, None]
    at = np.searchsorted(rows, force)
    depth_shapes, split_shapes, labels = [], [], []
    for zeta in FRAME_SEARCH_ZETA:
        w = 2 * np.pi * FRAME_SEARCH_HZ[None, :]
        den = s * s + 2 * zeta * w * s + w * w
        for shapes, g in ((depth_shapes, 2 * zeta * w * s / den),  # dH/d depth at depth = split = 0
                          (split_shapes, -(2 * s * s + 2 * zeta * w * s) / den)):  # dH/d split
            z = F * g
            col = np.zeros((rows.size, FRAME_SEARCH_HZ.size))
            col[at] = np.where(part[:, None] == 0, z.real, z.imag)
            shapes.append(col)
        labels += [(float(f), zeta) for f in FRAME_SEARCH_HZ]
    reduction, amplitudes = _explained_by_pairs(problem, m0, calibration_columns, np.concatenate(depth_shapes, axis=1),
                                                np.concatenate(split_shapes, axis=1))
    modes = np.array([f for f, _ in labels])
    # above the highest excitation frequency a mode's skirt is a smooth lead or lag across the sweep (a
    # channel's delay, the load cell's own skirt): no point of the day sees both its sides
    reduction = np.where(modes > float(np.max(frequency_hz)), -np.inf, reduction)
    if load_cell_hz is not None:
        near = np.abs(np.log(modes / load_cell_hz)) < np.log(1.0 + LOAD_CELL_BAND)
        reduction = np.where(near, -np.inf, reduction)
    best = int(np.argmax(reduction))
    f, zeta = labels[best]
    return {"frequency_hz": f, "zeta": zeta, "depth": float(amplitudes[0, best]), "split": float(amplitudes[1, best])}


def _explained_by_pairs(problem: Problem, m0: np.ndarray, columns: list[Column], C1: np.ndarray,
                        C2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per pair of columns (``C1[:, j]``, ``C2[:, j]``, on ``problem.rows``): the chi-square the pair
    removes from the calibrated fit's residual once the calibration's columns (and their priors) are
    projected off both, and the pair's two coefficients."""
    rows = problem.rows
    w = 1.0 / problem.sigma[rows]
    r = (problem.d - m0)[rows] * w
    J = np.column_stack([c.values[rows] for c in columns]) * w[:, None] if columns else np.zeros((rows.size, 0))
    widths = np.array([c.prior if c.prior is not None else np.inf for c in columns])
    P = np.diag(np.where(np.isfinite(widths), 1.0 / np.where(np.isfinite(widths), widths, 1.0), 0.0))
    A = np.vstack([J, P])
    norms = np.linalg.norm(A, axis=0)
    Q, _ = np.linalg.qr(A / np.where(norms > 0, norms, 1.0))
    pad = np.zeros((P.shape[0], C1.shape[1]))

    def perp(M: np.ndarray) -> np.ndarray:
        return M - Q @ (Q.T @ M)

    r_p = perp(np.concatenate([r, np.zeros(P.shape[0])])[:, None])[:, 0]
    X1, X2 = perp(np.vstack([C1 * w[:, None], pad])), perp(np.vstack([C2 * w[:, None], pad]))
    a, b, c = (np.einsum("ij,ij->j", X, Y) for X, Y in ((X1, X1), (X1, X2), (X2, X2)))
    u, v = X1.T @ r_p, X2.T @ r_p
    det = a * c - b * b
    ok = det > 1e-12 * np.maximum(a * c, 1e-300)
    det = np.where(ok, det, 1.0)
    x1, x2 = np.where(ok, (c * u - b * v) / det, 0.0), np.where(ok, (a * v - b * u) / det, 0.0)
    return np.where(ok, x1 * u + x2 * v, 0.0), np.vstack([x1, x2])
