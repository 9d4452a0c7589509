"""What a bench command may ask: every ``cmd/<verb>`` is checked here BEFORE it is answered.

A command that passes cannot fail later for what it asked (the sources apply it between blocks,
in the source thread, where a refusal would stop the pipeline): its numbers are finite, of the
right type, its keys known, the excitation frequency inside ``[MIN_FREQUENCY_HZ, fs / 10]`` (and
the generator's range) and the peak coil current ``|offset| + I_pp / 2`` within the bench's
limit.  The limit is checked on the operating point the command leads to (the last one commanded,
with this command's changes), so two commands that are each fine cannot add up to too much.

That point is a :class:`hystbench.messages.OperatingPoint`, the type the blocks carry: the commands
set its frequency, current and offset (what the generator plays once they are applied); its
``output_on``, ``settling`` and ``table`` pass through unchanged (the sources say those on every
block; the current limit holds whether the output is on or not, as it may be switched on later).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any, Mapping

from ..errors import ConfigError
from ..messages import OperatingPoint

__all__ = ["Limits", "check_command", "check_frequency", "check_current", "COMMANDS",
           "MIN_FREQUENCY_HZ", "MIN_SAMPLES_PER_PERIOD", "MAX_SWEEP_POINTS", "MAX_DWELL_S"]

#: The verbs, with the arguments each takes.
COMMANDS: Mapping[str, tuple[str, ...]] = {
    "start_sweep": ("frequencies_hz", "current_pp_a", "dwell_s"),
    "stop_sweep": (),
    "set_excitation": ("frequency_hz", "current_pp_a", "offset_a"),
    "output": ("on",),
}
#: Below this the estimator's window of whole periods (10 by default) grows past what a ring and
#: a live display are for; quasi-static loops are measured from 1 Hz.
MIN_FREQUENCY_HZ = 1.0
#: At least this many samples per period: the phase fits need the waveform, not its aliases.
MIN_SAMPLES_PER_PERIOD = 10
MAX_SWEEP_POINTS = 1000
MAX_DWELL_S = 86_400.0
#: The signal generator's frequency range (drivers.protocols.scpi.GENERATOR["frequency_hz"]).
GENERATOR_MAX_HZ = 1e5


@dataclass(frozen=True)
class Limits:
    """The bench's limits: sample rate (-> frequency range) and the peak coil current."""

    fs_hz: float
    max_current_a: float

    @property
    def max_frequency_hz(self) -> float:
        return min(self.fs_hz / MIN_SAMPLES_PER_PERIOD, GENERATOR_MAX_HZ)

    def frequency_text(self) -> str:
        return (f"[{MIN_FREQUENCY_HZ:g}, {self.max_frequency_hz:g}] Hz (at least {MIN_SAMPLES_PER_PERIOD} "
                f"samples per period at {self.fs_hz:g} S/s)")


def _show(value: Any) -> str:
    """``repr(value)``, cut short (a refusal quotes what it refused, not a megabyte of it)."""
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def _number(name: str, value: Any) -> float:
    """A finite number (not a bool, not a string), as float."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ConfigError(f"{name} must be a number, got {_show(value)}")
    try:
        x = float(value)
    except OverflowError:
        x = math.inf
    if not math.isfinite(x):
        raise ConfigError(f"{name} must be a finite number, got {_show(value)}")
    return x


def check_frequency(name: str, value: Any, limits: Limits) -> float:
    f = _number(name, value)
    if not MIN_FREQUENCY_HZ <= f <= limits.max_frequency_hz:
        raise ConfigError(f"{name} = {f:g} Hz is outside {limits.frequency_text()}")
    return f


def check_current(what: str, point: OperatingPoint, limits: Limits) -> None:
    if point.current_pp_a < 0:
        raise ConfigError(f"{what}: current_pp_a must be >= 0, got {point.current_pp_a:g}")
    if point.peak_a > limits.max_current_a * (1 + 1e-9):
        raise ConfigError(f"{what}: peak current |offset| + I_pp/2 = {point.peak_a:.4g} A exceeds the bench's "
                          f"limit of {limits.max_current_a:g} A (I_pp <= {2 * limits.max_current_a:g} A at offset 0)")


def check_command(verb: Any, args: Any, limits: Limits, point: OperatingPoint,
                  sweep_defaults: Mapping[str, Any] | None = None) -> tuple[dict[str, Any], OperatingPoint]:
    """``(arguments, point)``: the checked arguments (floats, bools, defaults filled in for a sweep)
    and the operating point after the command; a ConfigError names what is refused and why."""
    if not isinstance(verb, str) or verb not in COMMANDS:
        raise ConfigError(f"unknown command {_show(verb)}; known: {', '.join(COMMANDS)}")
    if not isinstance(args, Mapping):
        raise ConfigError(f"{verb}: the arguments must be a JSON object, got {type(args).__name__}")
    unknown = sorted(map(str, set(args) - set(COMMANDS[verb])))
    if unknown:
        known = ", ".join(COMMANDS[verb]) or "none"
        raise ConfigError(f"{verb}: unknown argument(s) {_show(unknown)}; it takes: {known}")
    if verb == "stop_sweep":
        return {}, point
    if verb == "output":
        if not isinstance(args.get("on"), bool):
            raise ConfigError(f"output: 'on' must be true or false, got {_show(args.get('on'))}")
        return {"on": args["on"]}, point
    if verb == "set_excitation":
        if not args:
            raise ConfigError(f"set_excitation: give at least one of {', '.join(COMMANDS[verb])}")
        out: dict[str, Any] = {}
        if "frequency_hz" in args:
            out["frequency_hz"] = check_frequency("set_excitation: frequency_hz", args["frequency_hz"], limits)
        for k in ("current_pp_a", "offset_a"):
            if k in args:
                out[k] = _number(f"set_excitation: {k}", args[k])
        new = replace(point, **out)
        check_current("set_excitation", new, limits)
        return out, new
    sw = dict(sweep_defaults or {})
    freqs = args.get("frequencies_hz", sw.get("frequencies_hz"))
    if not isinstance(freqs, (list, tuple)) or not 1 <= len(freqs) <= MAX_SWEEP_POINTS:
        raise ConfigError(f"start_sweep: frequencies_hz must be a list of 1 to {MAX_SWEEP_POINTS} frequencies, "
                          f"got {_show(freqs)}")
    fs = [check_frequency(f"start_sweep: frequencies_hz[{k}]", f, limits) for k, f in enumerate(freqs)]
    ipp = _number("start_sweep: current_pp_a", args.get("current_pp_a", sw.get("current_pp_a")))
    dwell = _number("start_sweep: dwell_s", args.get("dwell_s", sw.get("dwell_s")))
    if not 0 < dwell <= MAX_DWELL_S:
        raise ConfigError(f"start_sweep: dwell_s must be in (0, {MAX_DWELL_S:g}] s, got {dwell:g}")
    new = replace(point, frequency_hz=fs[-1], current_pp_a=ipp)
    check_current("start_sweep", new, limits)
    return {"frequencies_hz": fs, "current_pp_a": ipp, "dwell_s": dwell}, new
