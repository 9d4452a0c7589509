"""How long the bench rings after its operating point changes: samples no estimate may use.

A change (output on from off, a new frequency, amplitude or waveform) starts transients that the
delays must not see:

- the instrument's modes: the load cell and frame (4450 Hz, zeta 0.012 in the paper: tau =
  1 / (zeta 2 pi fn) = 3 ms, a whole period at 320 Hz), the charge amplifier's low-pass, frame
  resonances, and, when the rig has them, the charge amplifier's high-pass and the flux
  integrator's leak (tau of a second: a DC step decays through them for seconds);
- the iron: after a change the first cycles run on a transient (virgin or shifted) minor loop
  until the loop closes; that is counted in periods by the estimator's ``settle_periods``.

:func:`settling_time_s` is ``SETTLE_TIME_CONSTANTS`` times the slowest time constant of the rig's
instrument chain (its poles, from the preset and the effects that are on): a transient as large as
the whole step is then below e^-10 = 4.5e-5 of it, under a 16-bit ADC's resolution of its range.
Measured on the simulated ``ecore_pm`` (output on from off at 320 and 480 Hz): the instrument phase
of a 10-period window starting at switch-on is 3-5 standard errors off, at 5 ms 0.5, from 10 ms
on within its scatter; the rule gives 30 ms.  The current amplifier of the simulated rig is ideal
(no transient of its own).
"""

from __future__ import annotations

import math
from typing import Any, Mapping

import numpy as np

from ..config import load_rig
from ..errors import BenchError

__all__ = ["SETTLE_TIME_CONSTANTS", "settling_time_s", "settle_samples"]

#: Time constants a transient is given to die out (e^-10 = 4.5e-5 of the step).
SETTLE_TIME_CONSTANTS = 10.0


def _time_constants(metadata: Mapping[str, Any]) -> list[float]:
    """Every time constant (s) of the rig's force and flux measurement chains."""
    from ..config.effects import resolve_effects
    from ..sim_backend.measurement import instrument_from_preset

    try:
        preset = load_rig(str(metadata.get("rig", "")))
    except BenchError:
        return []  # an unknown rig: nothing known to wait for
    given = metadata.get("effects")
    if isinstance(given, Mapping):  # a simulated rig's recording: the effects that were on
        effects = {k: dict(v) for k, v in given.items() if isinstance(v, Mapping)}
        core = "instrument_filter" in effects
    else:  # hardware: the preset's effects, and the instrument is always there
        try:
            effects = resolve_effects(preset.get("effects", {}), None, str(preset.get("_source", "preset")))
        except BenchError:
            effects = {}
        core = True
    taus: list[float] = []
    if isinstance(preset.get("instrument"), Mapping):
        for _, a, _ in instrument_from_preset(preset, effects).sections(core=core):
            for pole in np.roots(a):
                if pole.real < 0:
                    taus.append(-1.0 / float(pole.real))
    leak = effects.get("integrator_leak")
    if leak is not None:
        taus.append(float(leak["time_constant_s"]))
    return taus


def settling_time_s(metadata: Mapping[str, Any]) -> float:
    """Seconds after a change of operating point before samples are steady again (0 for a rig
    the presets do not know).

    >>> round(settling_time_s({"rig": "ecore_pm"}) * 1e3, 1)  # 10 x the frame's 2.98 ms
    29.8
    """
    taus = _time_constants(metadata)
    return SETTLE_TIME_CONSTANTS * max(taus) if taus else 0.0


def settle_samples(settle_s: float, settle_periods: float, fs_hz: float, frequency_hz: float) -> int:
    """Samples to skip at the start of a run: ``settle_s`` (the instrument's ringing) or
    ``settle_periods`` periods of ``frequency_hz`` (the iron's loop), whichever is longer; the live
    estimator and the offline reader skip the same."""
    periods = settle_periods * (fs_hz / frequency_hz) if frequency_hz > 0 else 0.0
    return int(math.ceil(max(settle_s * fs_hz, periods)))
