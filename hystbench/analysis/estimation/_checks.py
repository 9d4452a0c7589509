"""Argument checks shared by the estimators: each raises ``ValueError`` naming the parameter."""

from __future__ import annotations

import math
from collections.abc import Iterable

import numpy as np

MIN_PERIODS = 2.0  # shortest record the estimators accept, in periods of the fundamental


def check_fs(fs_hz: float) -> float:
    """Sample rate: finite and > 0 (Hz)."""
    try:
        value = float(fs_hz)
    except (TypeError, ValueError):
        raise ValueError(f"fs_hz must be a number (Hz), got {fs_hz!r}") from None
    if not math.isfinite(value) or value <= 0.0:
        raise ValueError(f"fs_hz must be finite and > 0 Hz, got {fs_hz!r}")
    return value


def check_nonnegative(value: float, name: str, *, allow_zero: bool = False) -> float:
    """A finite number, > 0 (or >= 0 with ``allow_zero``)."""
    try:
        out = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a number, got {value!r}") from None
    if not math.isfinite(out) or out < 0.0 or (out == 0.0 and not allow_zero):
        raise ValueError(f"{name} must be finite and {'>=' if allow_zero else '>'} 0, got {value!r}")
    return out


def check_freq(frequency_hz: float, fs_hz: float, highest_harmonic: int = 1, *,
               name: str = "frequency_hz") -> float:
    """Excitation frequency: finite, > 0, and ``highest_harmonic * frequency_hz`` below Nyquist."""
    try:
        value = float(frequency_hz)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a number (Hz), got {frequency_hz!r}") from None
    if not math.isfinite(value) or value <= 0.0:
        raise ValueError(f"{name} must be finite and > 0 Hz, got {frequency_hz!r}")
    if highest_harmonic * value >= fs_hz / 2.0:
        what = name if highest_harmonic == 1 else f"{name} ({highest_harmonic} x {value:g} Hz)"
        raise ValueError(f"{what} is at or above the Nyquist frequency fs/2 = {fs_hz / 2.0:g} Hz")
    return value


def check_harmonics(harmonics: int | Iterable[int]) -> tuple[int, ...]:
    """Harmonic numbers: positive, distinct integers; returned sorted."""
    items = (harmonics,) if isinstance(harmonics, (int, np.integer)) else tuple(harmonics)
    if not items:
        raise ValueError("harmonics must name at least one harmonic")
    out = []
    for k in items:
        if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or k < 1:
            raise ValueError(f"harmonics must be positive integers, got {k!r}")
        out.append(int(k))
    if len(set(out)) != len(out):
        raise ValueError(f"harmonics must be distinct, got {items!r}")
    return tuple(sorted(out))


def as_record(x: object, name: str, axis: int) -> np.ndarray:
    """A real, finite float array with the time axis moved last."""
    arr = np.asarray(x)
    if arr.ndim == 0:
        raise ValueError(f"{name} must be an array of samples, got a scalar")
    if arr.dtype.kind not in "iuf":
        raise ValueError(f"{name} must hold real numbers, got dtype {arr.dtype}")
    try:
        arr = np.moveaxis(arr.astype(np.float64, copy=False), axis, -1)
    except np.exceptions.AxisError as err:
        raise ValueError(f"axis {axis} is out of range for {name} with shape {np.shape(x)}") from err
    if not np.all(np.isfinite(arr)):
        bad = int(np.count_nonzero(~np.isfinite(arr)))
        raise ValueError(f"{name} contains {bad} NaN or infinite sample(s)")
    return arr


def check_length(arr: np.ndarray, name: str, fs_hz: float, frequency_hz: float, n_params: int = 0) -> int:
    """At least two periods of ``frequency_hz`` and more samples than fitted parameters."""
    n = arr.shape[-1]
    need = max(math.ceil(MIN_PERIODS * fs_hz / frequency_hz - 1e-9), n_params + 2)
    if n < need:
        raise ValueError(
            f"{name} has {n} samples, shorter than two periods of {frequency_hz:g} Hz at fs = {fs_hz:g} Hz "
            f"(need >= {need})"
        )
    return n


def check_not_flat(arr: np.ndarray, name: str) -> None:
    """Every record must vary (a constant channel carries no phase)."""
    flat = np.ptp(arr, axis=-1) == 0.0
    if np.any(flat):
        where = "" if arr.ndim == 1 else f" ({int(np.count_nonzero(flat))} record(s))"
        raise ValueError(f"{name} is flat (zero variance){where}: it carries no phase")


def check_same_shape(x: np.ndarray, y: np.ndarray) -> None:
    """Refuse two series that do not pair sample by sample (numpy would broadcast them silently)."""
    if x.shape != y.shape:
        raise ValueError(f"y has shape {y.shape} but x has shape {x.shape}; they must match")
