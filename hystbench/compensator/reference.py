"""Force references: the periodic force the actuator should produce, as one period table.

Three ways to say one: a sine with offset (``offset=170,amp=40,freq=320``, optional ``phase=DEG``),
a multi-sine (the same plus harmonics, ``h2=5``, ``h3=2@90``: amplitude, optionally @phase in
degrees), or any periodic table (one period, uniformly sampled, e.g. a CSV column).  Every
component is ``amp sin(2 pi k f t + phase)``.  A reference with no AC part is refused: the
piezoelectric load cell cannot see a static force, so nothing could be learned or checked.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np

from ..errors import ConfigError

__all__ = ["ForceReference", "DEFAULT_POINTS"]

DEFAULT_POINTS = 1000
_KEYS = ("offset", "amp", "freq", "phase")


@dataclass(frozen=True)
class ForceReference:
    """One period of the desired force (N) at ``frequency_hz``; phase 0 is the table's sample 0."""

    frequency_hz: float
    force_n: np.ndarray
    description: str

    def __post_init__(self) -> None:
        f = np.asarray(self.force_n, dtype=float)
        if not (math.isfinite(self.frequency_hz) and self.frequency_hz > 0):
            raise ConfigError(f"force reference: frequency must be a positive number of Hz, got {self.frequency_hz!r}")
        if f.ndim != 1 or f.size < 16 or not np.all(np.isfinite(f)):
            raise ConfigError(f"force reference: one period of at least 16 finite values is needed, got shape {f.shape}")
        if np.ptp(f) <= 1e-12 * max(1.0, float(np.max(np.abs(f)))):
            raise ConfigError("force reference: it has no AC part; a piezoelectric load cell cannot see a static "
                              "force, so give an amplitude > 0")
        object.__setattr__(self, "force_n", f)

    @property
    def n(self) -> int:
        return int(self.force_n.size)

    @property
    def range_n(self) -> tuple[float, float]:
        return float(self.force_n.min()), float(self.force_n.max())

    def highest_hz(self, share: float = 1e-6) -> float:
        """The highest frequency the reference holds: its highest harmonic above ``share`` of its
        largest AC one (a table's rounding below it)."""
        mag = np.abs(np.fft.rfft(self.force_n)[1:])
        k = np.flatnonzero(mag > share * mag.max())
        return float((k[-1] + 1) * self.frequency_hz) if k.size else 0.0

    @classmethod
    def multisine(cls, offset_n: float, frequency_hz: float, components: Sequence[tuple[float, float, float]], *,
                  n_points: int = DEFAULT_POINTS, description: str | None = None) -> "ForceReference":
        """offset + sum amp_k sin(2 pi k f t + phase_k) for ``components`` [(k, amp_n, phase_deg)]."""
        ph = np.arange(n_points) / n_points
        f = np.full(n_points, float(offset_n))
        for k, amp, phase_deg in components:
            if int(k) != k or k < 1:
                raise ConfigError(f"force reference: harmonic numbers are integers >= 1, got {k!r}")
            if k >= n_points // 2:  # the table would alias it (h99999999999 was taken as 1 N "tracked")
                raise ConfigError(f"force reference: harmonic {int(k)} is beyond what a period of {n_points} points "
                                  f"holds (below {n_points // 2})")
            f += float(amp) * np.sin(2 * np.pi * int(k) * ph + math.radians(float(phase_deg)))
        desc = description or f"offset {offset_n:g} N, " + ", ".join(
            f"{a:g} N at {int(k) * frequency_hz:g} Hz" + (f" ({p:g} deg)" if p else "") for k, a, p in components)
        return cls(float(frequency_hz), f, desc)

    @classmethod
    def sine(cls, offset_n: float, amplitude_n: float, frequency_hz: float, phase_deg: float = 0.0,
             *, n_points: int = DEFAULT_POINTS) -> "ForceReference":
        return cls.multisine(offset_n, frequency_hz, [(1, amplitude_n, phase_deg)], n_points=n_points)

    @classmethod
    def parse(cls, spec: str, *, n_points: int = DEFAULT_POINTS) -> "ForceReference":
        """From ``offset=170,amp=40,freq=320[,phase=DEG][,h2=AMP[@DEG],...]``."""
        values: dict[str, float] = {}
        harmonics: list[tuple[int, float, float]] = []
        for part in (p.strip() for p in spec.split(",") if p.strip()):
            key, sep, raw = part.partition("=")
            key = key.strip().lower()
            if not sep:
                raise ConfigError(f"--force {spec!r}: {part!r} is not KEY=VALUE (keys: {', '.join(_KEYS)}, hK)")
            if key.startswith("h") and key[1:].isdigit():
                amp_s, _, ph_s = raw.partition("@")
                harmonics.append((int(key[1:]), _number(spec, key, amp_s), _number(spec, key, ph_s) if ph_s else 0.0))
                continue
            if key not in _KEYS:
                raise ConfigError(f"--force {spec!r}: unknown key {key!r}; keys: {', '.join(_KEYS)}, hK (harmonic K)")
            if key in values:
                raise ConfigError(f"--force {spec!r}: {key!r} given twice")
            values[key] = _number(spec, key, raw)
        for key in ("offset", "amp", "freq"):
            if key not in values:
                raise ConfigError(f"--force {spec!r}: missing {key}= (e.g. offset=170,amp=40,freq=320)")
        if values["amp"] < 0 or any(a < 0 for _, a, _ in harmonics):
            raise ConfigError(f"--force {spec!r}: amplitudes must be >= 0 (use phase= to flip a sign)")
        comps = [(1, values["amp"], values.get("phase", 0.0)), *harmonics]
        return cls.multisine(values["offset"], values["freq"], comps, n_points=n_points)

    @classmethod
    def from_csv(cls, path: str | Path, frequency_hz: float, *, column: str = "force_N") -> "ForceReference":
        """One period from a CSV file with a header naming ``column`` (other columns ignored)."""
        path = Path(path)
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("error", UserWarning)  # numpy only warns about an empty file
                data = np.genfromtxt(path, delimiter=",", names=True, encoding="utf-8-sig")  # Excel writes a BOM
        except (OSError, ValueError) as err:
            raise ConfigError(f"{path}: cannot read a force table: {err}") from err
        except UserWarning as err:
            raise ConfigError(f"{path}: cannot read a force table: the file is empty (it needs a header "
                              f"naming {column!r}, then one period of values)") from err
        if data.dtype.names is None or column not in data.dtype.names:
            raise ConfigError(f"{path}: no column {column!r}; it has {list(data.dtype.names or [])}")
        values = np.atleast_1d(data[column]).astype(float)
        if not np.all(np.isfinite(values)):
            bad = int(np.argmax(~np.isfinite(values)))
            raise ConfigError(f"{path}:{bad + 2}: column {column!r} is not a finite number")
        return cls(float(frequency_hz), values, f"{path.name} ({values.size} points) at {frequency_hz:g} Hz")


def _number(spec: str, key: str, raw: str) -> float:
    try:
        value = float(raw)
    except ValueError as err:
        raise ConfigError(f"--force {spec!r}: {key}={raw!r} is not a number") from err
    if not math.isfinite(value):
        raise ConfigError(f"--force {spec!r}: {key}={raw!r} is not finite")
    return value
