"""What a bench command may ask: every ``cmd/<verb>`` is checked here BEFORE it is answered.

A command that passes cannot fail later for what it asked (the sources apply it between blocks,
in the source thread, where a refusal would stop the pipeline): its keys known, each argument of
the type and in the range its :class:`~hystbench.config.schema.Key` in :data:`ARGUMENTS` says (the
one validator of every TOML file; a number is first a finite one, as JSON may carry ``1e999``), and
the rules no single argument can say: the excitation frequency inside ``[MIN_FREQUENCY_HZ, fs / 10]``
(and the generator's range), at most ``MAX_SWEEP_POINTS`` frequencies in a sweep, and the peak coil
current ``|offset| + I_pp / 2`` within the bench's limit.  The limit is checked on the operating point the command leads to (the last one commanded,
with this command's changes), so two commands that are each fine cannot add up to too much; the
service checks a sweep's every point again when it applies it (``set_excitation`` may have moved
the offset meanwhile).  The limit is the bench's command limit: the trip level less its margin
(:mod:`hystbench.drivers.safety`), so an accepted command cannot trip the amplifier.

That point is a :class:`hystbench.messages.OperatingPoint`, the type the blocks carry: the commands
set its frequency, current and offset (what the generator plays once they are applied); its
``output_on``, ``settling`` and ``table`` pass through unchanged (the sources say those on every
block; the current limit holds whether the output is on or not, as it may be switched on later).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any, Mapping, Sequence

from ..config.schema import NUM, OPTIONAL, Key
from ..errors import ConfigError
from ..messages import OperatingPoint

__all__ = ["Limits", "show", "check_command", "check_frequency", "check_current", "ARGUMENTS", "COMMANDS",
           "MIN_FREQUENCY_HZ", "MIN_SAMPLES_PER_PERIOD", "MAX_SWEEP_POINTS", "MAX_DWELL_S", "check_dwell"]

#: Below this the estimator's window of whole periods (10 by default) grows past what a ring and
#: a live display are for; quasi-static loops are measured from 1 Hz.
MIN_FREQUENCY_HZ = 1.0
#: At least this many samples per period: the phase fits need the waveform, not its aliases.
MIN_SAMPLES_PER_PERIOD = 10
MAX_SWEEP_POINTS = 1000
MAX_DWELL_S = 86_400.0
#: The signal generator's frequency range (drivers.protocols.scpi.GENERATOR["frequency_hz"]).
GENERATOR_MAX_HZ = 1e5

#: Any finite number: what every numeric argument is checked as first.
_FINITE = Key(NUM, None, "a finite number")
#: A frequency; its range is the bench's (:meth:`Limits.max_frequency_hz`), a rule: :func:`check_frequency`.
_FREQUENCY = Key(NUM, None, "frequencies", "Hz")
#: The verbs, and what each argument may hold.  ``start_sweep`` fills what it is not given from
#: the daemon file's [sweep]; ``set_excitation`` changes what it is given.
ARGUMENTS: Mapping[str, Mapping[str, Key]] = {
    "start_sweep": {
        "frequencies_hz": Key(list, OPTIONAL, "the sweep's frequencies, in order", "Hz", items=_FREQUENCY,
                              nonempty=True),
        "current_pp_a": Key(NUM, OPTIONAL, "excitation current, peak to peak", "A", ge=0.0),
        "dwell_s": Key(NUM, OPTIONAL, "time at each frequency", "s", gt=0.0, le=MAX_DWELL_S),
    },
    "stop_sweep": {},
    "set_excitation": {
        "frequency_hz": Key(NUM, OPTIONAL, "excitation frequency", "Hz"),
        "current_pp_a": Key(NUM, OPTIONAL, "excitation current, peak to peak", "A", ge=0.0),
        "offset_a": Key(NUM, OPTIONAL, "DC offset of the current", "A"),
    },
    "output": {"on": Key(bool, None, "the amplifier's output on")},
    "clear_fault": {},  # the operator has seen why the excitation tripped the bench: output on may follow
}
#: The verbs, with the arguments each takes.
COMMANDS: Mapping[str, tuple[str, ...]] = {verb: tuple(args) for verb, args in ARGUMENTS.items()}


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


def show(value: Any, limit: int = 60) -> str:
    """``repr(value)``, cut to ``limit`` characters (a refusal quotes what it refused, not a megabyte of it)."""
    text = repr(value)
    return text if len(text) <= limit else text[:limit - 3] + "..."


def _number(name: str, value: Any, spec: Key = _FINITE) -> float:
    """``value`` as float if it is a finite number (not a bool, not a string) that ``spec`` allows;
    the ConfigError names ``name`` ('verb: argument') and says the range, with its unit."""
    bad = _FINITE.problem(value) or spec.problem(value)
    if bad:
        unit = f" {spec.unit}" if spec.unit and bad == f"must be {spec.range_text()}" else ""
        raise ConfigError(f"{name} {bad}{unit}, got {show(value)}")
    return float(value)


def check_frequency(name: str, value: Any, limits: Limits) -> float:
    """``value`` as a frequency the bench can play and sample (Hz); one check for a command and a
    daemon file, so a value the daemon would refuse as a command is refused in its file already."""
    f = _number(name, value)
    if not MIN_FREQUENCY_HZ <= f <= limits.max_frequency_hz:
        raise ConfigError(f"{name} = {f:g} Hz is outside {limits.frequency_text()}")
    return f


def check_current(what: str, point: OperatingPoint, limits: Limits) -> None:
    """Refuse an operating point whose peak coil current exceeds the bench's limit, before the
    amplifier is asked to drive it."""
    if point.peak_a > limits.max_current_a * (1 + 1e-9):
        raise ConfigError(f"{what}: peak current |offset| + I_pp/2 = {point.peak_a:.4g} A exceeds the bench's "
                          f"limit of {limits.max_current_a:g} A (I_pp <= {2 * limits.max_current_a:g} A at offset 0)")


def check_dwell(what: str, dwell_s: float, frequencies_hz: Sequence[float], periods: float, why: str) -> None:
    """Refuse a sweep whose dwell gives some point fewer than ``periods`` whole periods of its
    frequency (``why``: what needs them, the estimator's settle and window): such a point is played,
    and nothing is measured at it.  ``what`` leads the message ("start_sweep: dwell_s = ")."""
    f = min(frequencies_hz)
    if dwell_s * f < periods * (1 - 1e-9):
        plural = "" if periods == 1 else "s"
        raise ConfigError(f"{what}{dwell_s:g} s is too short at {f:g} Hz, where a point needs {periods:g} "
                          f"period{plural} ({why}), {periods / f:.4g} s: give dwell_s >= {periods / f:.4g} s, or leave "
                          "that frequency out")


def check_command(verb: Any, args: Any, limits: Limits, point: OperatingPoint,
                  sweep_defaults: Mapping[str, Any] | None = None,
                  point_periods: tuple[float, str] = (0.0, "")) -> tuple[dict[str, Any], OperatingPoint]:
    """``(arguments, point)``: the checked arguments (floats, bools, defaults filled in for a sweep)
    and the operating point after the command; a ConfigError names what is refused and why.
    ``point_periods``: the whole periods each sweep point needs, and what needs them (check_dwell)."""
    if not isinstance(verb, str) or verb not in COMMANDS:
        raise ConfigError(f"unknown command {show(verb)}; known: {', '.join(COMMANDS)}")
    if not isinstance(args, Mapping):
        raise ConfigError(f"{verb}: the arguments must be a JSON object, got {type(args).__name__}")
    unknown = sorted(map(str, set(args) - set(COMMANDS[verb])))
    if unknown:
        known = ", ".join(COMMANDS[verb]) or "none"
        raise ConfigError(f"{verb}: unknown argument(s) {show(unknown)}; it takes: {known}")
    if verb in ("stop_sweep", "clear_fault"):
        return {}, point
    keys = ARGUMENTS[verb]
    if verb == "output":
        if keys["on"].problem(args.get("on")):  # "'on'": the word alone would read as part of the sentence
            raise ConfigError(f"output: 'on' must be true or false, got {show(args.get('on'))}")
        return {"on": args["on"]}, point
    if verb == "set_excitation":
        if not args:
            raise ConfigError(f"set_excitation: give at least one of {', '.join(COMMANDS[verb])}")
        out = {k: _number(f"set_excitation: {k}", args[k], spec) for k, spec in keys.items() if k in args}
        if "frequency_hz" in out:
            check_frequency("set_excitation: frequency_hz", out["frequency_hz"], limits)
        new = replace(point, **out)
        check_current("set_excitation", new, limits)
        return out, new
    given = {k: args.get(k, (sweep_defaults or {}).get(k)) for k in keys}  # start_sweep
    freqs = given["frequencies_hz"]
    if not isinstance(freqs, (list, tuple)) or not 1 <= len(freqs) <= MAX_SWEEP_POINTS:
        raise ConfigError(f"start_sweep: frequencies_hz must be a list of 1 to {MAX_SWEEP_POINTS} frequencies, "
                          f"got {show(freqs)}")
    fs = [check_frequency(f"start_sweep: frequencies_hz[{k}]", f, limits) for k, f in enumerate(freqs)]
    ipp = _number("start_sweep: current_pp_a", given["current_pp_a"], keys["current_pp_a"])
    dwell = _number("start_sweep: dwell_s", given["dwell_s"], keys["dwell_s"])
    check_dwell("start_sweep: dwell_s = ", dwell, fs, *point_periods)
    new = replace(point, frequency_hz=fs[-1], current_pp_a=ipp)
    check_current("start_sweep", new, limits)
    return {"frequencies_hz": fs, "current_pp_a": ipp, "dwell_s": dwell}, new
