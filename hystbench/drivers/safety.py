"""The configured maximum current, enforced in the driver layer.

The coil current is (generator voltage) x (amplifier gain), so neither driver can check it alone:
both hold the same :class:`CurrentBudget`.  The generator asks it before any amplitude, offset or
waveform change; the amplifier before any gain or current-limit change.  Refusals raise
:class:`SafetyLimitError` before a byte is sent.
"""

from __future__ import annotations

import threading

from ..errors import ConfigError, InstrumentError

__all__ = ["CurrentBudget", "SafetyLimitError"]


class SafetyLimitError(InstrumentError, ValueError):
    """A command would let the coil current exceed the configured maximum."""


class CurrentBudget:
    """``max_current_a`` and what the two drivers last set: generator peak |V| and amplifier gain."""

    def __init__(self, max_current_a: float, gain_a_per_v: float) -> None:
        if not max_current_a > 0 or not gain_a_per_v > 0:
            raise ConfigError(f"max_current_a ({max_current_a}) and gain_a_per_v ({gain_a_per_v}) must be > 0")
        self.max_current_a = float(max_current_a)
        self.gain_a_per_v = float(gain_a_per_v)
        self.command_peak_v = 0.0  # generator |offset| + amplitude/2, or the waveform's peak
        self._lock = threading.Lock()

    def peak_current_a(self, peak_v: float | None = None, gain_a_per_v: float | None = None) -> float:
        return (self.command_peak_v if peak_v is None else peak_v) * (
            self.gain_a_per_v if gain_a_per_v is None else gain_a_per_v)

    def check_command(self, who: str, command: str, peak_v: float) -> None:
        with self._lock:
            i = self.peak_current_a(peak_v=abs(peak_v))
            if i > self.max_current_a * (1 + 1e-9):
                raise SafetyLimitError(
                    f"{who}: refused {command!r}: peak {abs(peak_v):.4g} V x {self.gain_a_per_v:g} A/V = "
                    f"{i:.4g} A exceeds max_current_a = {self.max_current_a:g} A")

    def check_gain(self, who: str, command: str, gain_a_per_v: float) -> None:
        with self._lock:
            i = self.peak_current_a(gain_a_per_v=gain_a_per_v)
            if i > self.max_current_a * (1 + 1e-9):
                raise SafetyLimitError(
                    f"{who}: refused {command!r}: generator peak {self.command_peak_v:.4g} V x {gain_a_per_v:g} A/V "
                    f"= {i:.4g} A exceeds max_current_a = {self.max_current_a:g} A")

    def check_limit(self, who: str, command: str, limit_a: float) -> None:
        if limit_a > self.max_current_a * (1 + 1e-9):
            raise SafetyLimitError(f"{who}: refused {command!r}: current limit {limit_a:g} A exceeds "
                                   f"max_current_a = {self.max_current_a:g} A")

    def commit_command(self, peak_v: float) -> None:
        with self._lock:
            self.command_peak_v = abs(float(peak_v))

    def commit_gain(self, gain_a_per_v: float) -> None:
        with self._lock:
            self.gain_a_per_v = float(gain_a_per_v)
