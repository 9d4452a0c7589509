"""The configured maximum current, enforced in the driver layer.

The coil current is (generator voltage) x (amplifier gain), so neither driver can check it alone:
both hold the same :class:`CurrentBudget`.  The generator asks it before any amplitude, offset or
waveform change; the amplifier before any gain or current-limit change.  Refusals raise
:class:`SafetyLimitError` before a byte is sent.

The peak a command may ask is the *command limit*: the smaller of the bench's ``max_current_a``
and the amplifier's trip level (its ``current_limit`` register), less ``margin`` of it
(``[bench] current_margin``, :data:`DEFAULT_MARGIN`).  The margin is what the measured current
may exceed the commanded peak by: the monitor's noise, the amplifier's distortion and the
overshoot of its response to a change.  Without it a command exactly at the trip level is
accepted and then trips the amplifier on the first noisy sample.
"""

from __future__ import annotations

import math
import threading

from ..errors import ConfigError, InstrumentError

__all__ = ["CurrentBudget", "SafetyLimitError", "DEFAULT_MARGIN", "command_limit"]

#: The share of the trip level kept free (5 %: 90 mA at 1.8 A).  On the emulated bench, with the
#: amplifier's distortion (0.002/A, 0.001/A^2), the monitor's noise (0.2 mA rms) and the 16-bit ADC,
#: the measured current exceeds the commanded peak by at most 0.7 % at the command limit
#: (tests/acquisition/test_current_limits.py measures it); docs/faults.md says how to set it for a
#: real amplifier (its overshoot on a step, its monitor's noise).
DEFAULT_MARGIN = 0.05


def command_limit(max_current_a: float, trip_a: float | None, margin: float) -> float:
    """The peak coil current a command may ask: ``min(max_current_a, trip_a) * (1 - margin)``."""
    return min(max_current_a, math.inf if trip_a is None else trip_a) * (1.0 - margin)


class SafetyLimitError(InstrumentError, ValueError):
    """A command would let the coil current exceed the configured maximum."""


class CurrentBudget:
    """``max_current_a`` and what the two drivers last set: generator peak |V|, amplifier gain and
    the amplifier's trip level (``trip_a``, None until known)."""

    def __init__(self, max_current_a: float, gain_a_per_v: float, *, margin: float = DEFAULT_MARGIN,
                 trip_a: float | None = None) -> None:
        if not max_current_a > 0 or not gain_a_per_v > 0:
            raise ConfigError(f"max_current_a ({max_current_a}) and gain_a_per_v ({gain_a_per_v}) must be > 0")
        if not 0 <= margin < 1:
            raise ConfigError(f"current margin must be in [0, 1), got {margin!r}")
        self.max_current_a = float(max_current_a)
        self.gain_a_per_v = float(gain_a_per_v)
        self.margin = float(margin)
        self.trip_a = None if trip_a is None else float(trip_a)
        self.command_peak_v = 0.0  # generator |offset| + amplitude/2, or the waveform's peak
        self._lock = threading.Lock()

    @property
    def command_limit_a(self) -> float:
        """The largest peak current a command may ask (:func:`command_limit`)."""
        return command_limit(self.max_current_a, self.trip_a, self.margin)

    def _limit_text(self) -> str:
        trip = f", amplifier trip {self.trip_a:g} A" if self.trip_a is not None else ""
        return (f"the command limit {self.command_limit_a:.4g} A (max_current_a {self.max_current_a:g} A{trip}, "
                f"less {100 * self.margin:g} % for noise and overshoot)")

    def peak_current_a(self, peak_v: float | None = None, gain_a_per_v: float | None = None) -> float:
        return (self.command_peak_v if peak_v is None else peak_v) * (
            self.gain_a_per_v if gain_a_per_v is None else gain_a_per_v)

    def check_command(self, who: str, command: str, peak_v: float) -> None:
        with self._lock:
            i = self.peak_current_a(peak_v=abs(peak_v))
            if not i <= self.command_limit_a * (1 + 1e-9):
                raise SafetyLimitError(
                    f"{who}: refused {command!r}: peak {abs(peak_v):.4g} V x {self.gain_a_per_v:g} A/V = "
                    f"{i:.4g} A exceeds {self._limit_text()}")

    def check_gain(self, who: str, command: str, gain_a_per_v: float) -> None:
        with self._lock:
            i = self.peak_current_a(gain_a_per_v=gain_a_per_v)
            if not i <= self.command_limit_a * (1 + 1e-9):
                raise SafetyLimitError(
                    f"{who}: refused {command!r}: generator peak {self.command_peak_v:.4g} V x {gain_a_per_v:g} A/V "
                    f"= {i:.4g} A exceeds {self._limit_text()}")

    def check_limit(self, who: str, command: str, limit_a: float) -> None:
        """A new trip level: at most ``max_current_a``, and not below what the generator plays
        (with the margin), or the amplifier would trip on the running excitation."""
        if not limit_a <= self.max_current_a * (1 + 1e-9):
            raise SafetyLimitError(f"{who}: refused {command!r}: current limit {limit_a:g} A exceeds "
                                   f"max_current_a = {self.max_current_a:g} A")
        with self._lock:
            need = self.peak_current_a()
            allowed = command_limit(self.max_current_a, limit_a, self.margin)
            if need > allowed * (1 + 1e-9):
                raise SafetyLimitError(f"{who}: refused {command!r}: the generator's peak {need:.4g} A would be "
                                       f"within {100 * self.margin:g} % of (or above) that trip level; lower the "
                                       "excitation first")

    def commit_command(self, peak_v: float) -> None:
        with self._lock:
            self.command_peak_v = abs(float(peak_v))

    def commit_gain(self, gain_a_per_v: float) -> None:
        with self._lock:
            self.gain_a_per_v = float(gain_a_per_v)

    def commit_limit(self, trip_a: float) -> None:
        """The amplifier's trip level as it now stands (written, or read back at open)."""
        with self._lock:
            self.trip_a = float(trip_a)
