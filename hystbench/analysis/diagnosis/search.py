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
from .vector import CHANNELS, Layout

__all__ = ["frame_mode_search", "frame_mode_columns", "mode_shapes", "FRAME_SEARCH_HZ", "FRAME_SEARCH_ZETA"]

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
    labels = [(float(f), zeta) for zeta in FRAME_SEARCH_ZETA for f in FRAME_SEARCH_HZ]
    shapes = mode_shapes(problem.layout, m0, frequency_hz, labels)
    if shapes is None:
        return {"frequency_hz": float(FRAME_SEARCH_HZ[0]), "zeta": FRAME_SEARCH_ZETA[0], "depth": 0.0, "split": 0.0}
    depth_shapes, split_shapes = (s[problem.rows] for s in shapes)
    reduction, amplitudes = _explained_by_pairs(problem, m0, calibration_columns, depth_shapes, split_shapes)
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


def frame_mode_columns(layout: Layout, m0: np.ndarray, frequency_hz: np.ndarray, mode: dict[str, float],
                       name: str = "frame_mode") -> list[Column]:
    """A mode's depth and split as columns of the fit (its closed-form shapes around ``m0``), on every
    number of the vector: what a mode found by the search predicts where it was not searched."""
    shapes = mode_shapes(layout, m0, frequency_hz, [(mode["frequency_hz"], mode["zeta"])])
    if shapes is None:
        return []
    return [Column(f"{name}.{what}", s[:, 0]) for what, s in zip(("depth", "split"), shapes)]


def mode_shapes(layout: Layout, m0: np.ndarray, frequency_hz: np.ndarray,
                modes: list[tuple[float, float]]) -> tuple[np.ndarray, np.ndarray] | None:
    """Each (frequency, damping) mode's change of the force harmonics per unit depth and per unit split
    (at depth = split = 0), as two arrays (numbers of ``m0``, modes); None when the day has no force."""
    force = np.flatnonzero((layout.channel == CHANNELS.index("force_N")) & (layout.harmonic > 0))
    if not force.size:
        return None
    # the model's complex force harmonic at each force row, and the row's part
    rec, k, part = layout.record[force], layout.harmonic[force], layout.part[force]
    key = rec * 1000 + k
    complex_of: dict[int, complex] = {}
    for i, kk, p in zip(force, key, part):
        complex_of[kk] = complex_of.get(kk, 0j) + (m0[i] if p == 0 else 1j * m0[i])
    F = np.array([complex_of[kk] for kk in key])[:, None]
    s = (2j * np.pi * k * np.asarray(frequency_hz, float)[rec])[:, None]
    w = 2 * np.pi * np.array([f for f, _ in modes])[None, :]
    zeta = np.array([z for _, z in modes])[None, :]
    den = s * s + 2 * zeta * w * s + w * w
    out = []
    for g in (2 * zeta * w * s / den,  # dH/d depth at depth = split = 0
              -(2 * s * s + 2 * zeta * w * s) / den):  # dH/d split
        z = F * g
        col = np.zeros((m0.size, len(modes)))
        col[force] = np.where(part[:, None] == 0, z.real, z.imag)
        out.append(col)
    return out[0], out[1]


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
