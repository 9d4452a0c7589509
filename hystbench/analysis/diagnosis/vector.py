"""The features of a bench day as one vector of real numbers, with what each number is.

The fits of a diagnosis are weighted least squares over every recording's harmonics at once; this
module lays the features out (record x channel x harmonic, real and imaginary parts) and keeps the
labels the report needs to say where a mismatch is.  The data fix the layout; a simulation is read
into the same rows.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from .features import RecordFeatures

__all__ = ["CHANNELS", "VIEWS", "Layout", "layout_of", "values_of", "line_values", "record_harmonics"]

#: The channels compared, and the view each channel's harmonics speak to (everything is referenced
#: to the current's fundamental, so the flux's harmonics are "flux vs current" and so on).
CHANNELS = ("current_A", "command_V", "flux_Wb", "force_N")
VIEWS = {"current_A": "current vs command", "command_V": "current vs command", "flux_Wb": "flux vs current",
         "force_N": "force vs current"}
#: Non-harmonic lines compared (mains pick-up reaches the sense leads and the charge amplifier).
LINE_CHANNELS = ("force_N", "sense_V")


@dataclass(frozen=True)
class Layout:
    """Which number of the vector is what: record index, channel, harmonic k, part (0 Re, 1 Im)."""

    record: np.ndarray
    channel: np.ndarray  # index into CHANNELS
    harmonic: np.ndarray
    part: np.ndarray
    se: np.ndarray  # the data's standard error of each number
    scale: np.ndarray  # the channel's largest harmonic amplitude in that record (the DC's: or the DC); the floor is relative to it

    @property
    def size(self) -> int:
        return int(self.record.size)

    def view(self) -> np.ndarray:
        return np.array([VIEWS[CHANNELS[c]] for c in self.channel])


def _rows(f: RecordFeatures):
    for ci, ch in enumerate(CHANNELS):
        h = f.harmonics.get(ch)
        if h is None:
            continue
        for k in range(h.size):
            if not np.isfinite(h[k]) or (ch == "flux_Wb" and k == 0):  # an integrator's DC is where it was reset
                continue
            if ch == "current_A" and k == 1:  # the replay's input (it drives the current each record had)
                continue
            yield ci, ch, k, 0
            if k > 0:
                yield ci, ch, k, 1


def layout_of(data: Sequence[RecordFeatures]) -> Layout:
    """The rows the data have (a simulation is read into the same rows)."""
    rec, chan, harm, part, se, scale = [], [], [], [], [], []
    for r, f in enumerate(data):
        amp = {ch: float(np.nanmax(np.abs(f.harmonics[ch][1:]))) for ch in CHANNELS if ch in f.harmonics}
        for ci, ch, k, p in _rows(f):
            rec.append(r)
            chan.append(ci)
            harm.append(k)
            part.append(p)
            se.append(float(f.se[ch][k]))
            scale.append(max(amp[ch], abs(f.harmonics[ch][0])) if k == 0 else amp[ch])
    return Layout(*(np.asarray(x) for x in (rec, chan, harm, part)), np.asarray(se, float), np.asarray(scale, float))


def values_of(features: Sequence[RecordFeatures], layout: Layout) -> np.ndarray:
    """The numbers of ``features`` in ``layout``'s rows (NaN where a simulation lacks one)."""
    table = np.full((len(features), len(CHANNELS), 1 + int(layout.harmonic.max(initial=0))), np.nan, complex)
    for r, f in enumerate(features):
        for ci, ch in enumerate(CHANNELS):
            h = f.harmonics.get(ch)
            if h is not None:
                n = min(h.size, table.shape[2])
                table[r, ci, :n] = h[:n]
    z = table[layout.record, layout.channel, layout.harmonic]
    return np.where(layout.part == 0, z.real, z.imag)


def line_values(features: Sequence[RecordFeatures]) -> tuple[np.ndarray, np.ndarray, list[tuple[int, str, float]]]:
    """Mains evidence: per record, channel and line, |a|^2 - 2 SE^2 (unbiased for the line's power
    whatever its phase, which runs on between records) with its null standard deviation 2 SE^2."""
    y, s, labels = [], [], []
    for r, f in enumerate(features):
        for ch in LINE_CHANNELS:
            for hz, (a, se) in f.lines.get(ch, {}).items():
                if se > 0 and np.isfinite(se) and np.isfinite(a):
                    y.append(abs(a) ** 2 - 2 * se ** 2)
                    s.append(2 * se ** 2)
                    labels.append((r, ch, float(hz)))
    return np.asarray(y, float), np.asarray(s, float), labels


def record_harmonics(values: np.ndarray, layout: Layout, record: int) -> dict[str, np.ndarray]:
    """Complex harmonics 0..K per channel of one record, read back from a vector's rows (what
    :func:`values_of` laid out; a row the layout lacks reads 0)."""
    out: dict[str, np.ndarray] = {}
    K = int(layout.harmonic.max(initial=0))
    for ci, ch in enumerate(CHANNELS):
        sel = (layout.record == record) & (layout.channel == ci)
        if not sel.any():
            continue
        h = np.zeros(K + 1, complex)
        for v, k, p in zip(values[: layout.size][sel], layout.harmonic[sel], layout.part[sel]):
            h[k] += v if p == 0 else 1j * v
        out[ch] = h
    return out
