"""Issue 16 item 1: no command can end the daemon or drive more than the bench's limit.

Every command is checked before it is answered (``bench_commands.check_command``); the property
test throws random verbs and arguments (NaN, infinities, huge, negative, wrong types, unknown
keys) at a running service, directly and over a real zenoh session on 127.0.0.1, and asserts that
each gets an answer, the service still runs, and the coil current in its log never went past the
limit.  Expected limits come from the shipped bench file (2 A max, the amplifier trips at 1.8 A,
gain 0.5 A/V) and the sample rate (100 kS/s), not from the checker."""

from __future__ import annotations

import json
import math
import threading
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hystbench.acquisition.bench_commands import ARGUMENTS, COMMANDS, Limits, check_command
from hystbench.acquisition.zenoh_bus import free_port, key, load_zenoh_config, open_session, peer_config
from hystbench.errors import BenchError, ConfigError
from hystbench.formats.mcaplog import iter_blocks
from hystbench.messages import OperatingPoint
from hystbench.service.daemon_config import load_daemon_config
from hystbench.service.service import BenchService

LIMITS = Limits(fs_hz=100_000.0, max_current_a=1.8)  # the shipped bench: amplifier current_limit_a 1.8 A
HERE = OperatingPoint(320.0, 1.4, 0.0)


@pytest.mark.parametrize("verb, args, match", [
    # the two commands: 50 A-pp is a 25 A peak, far above the bench's 1.8 A
    ("set_excitation", {"frequency_hz": 320, "current_pp_a": 50}, r"25 A exceeds the bench's limit of 1\.8 A"),
    ("start_sweep", {"frequencies_hz": [160], "current_pp_a": 50}, r"25 A exceeds the bench's limit of 1\.8 A"),
    ("set_excitation", {"current_pp_a": 3.0, "offset_a": 0.5}, r"peak current .* = 2 A exceeds"),  # 0.5 + 1.5
    ("set_excitation", {"frequency_hz": float("nan")}, "must be a finite number"),
    ("set_excitation", {"frequency_hz": 10**400}, "must be a finite number"),
    ("set_excitation", {"frequency_hz": "320"}, "must be a number"),
    ("set_excitation", {"frequency_hz": True}, "must be a number"),
    ("set_excitation", {"frequency_hz": 50_000.0}, r"outside \[1, 10000\] Hz"),  # Nyquist itself; > fs/10
    ("set_excitation", {"frequency_hz": 0.0}, r"outside \[1, 10000\] Hz"),
    ("set_excitation", {"current_pp_a": -1.0}, "must be >= 0"),
    ("set_excitation", {}, "give at least one of"),
    ("set_excitation", {"volume": 11}, "unknown argument"),
    ("output", {"on": "false"}, "'on' must be true or false"),  # a string that bool() would call True
    ("output", {}, "'on' must be true or false"),
    ("stop_sweep", {"now": 1}, "unknown argument"),
    ("start_sweep", {"frequencies_hz": []}, "list of 1 to"),
    ("start_sweep", {"frequencies_hz": 320}, "list of 1 to"),
    ("start_sweep", {"dwell_s": -1}, r"dwell_s must be in \(0"),
    ("start_sweep", {"dwell_s": math.inf}, "finite"),
    ("self_destruct", {}, "unknown command"),
    ("output", [1, 2], "must be a JSON object"),
])
def test_bad_commands_are_refused_with_the_reason(verb, args, match) -> None:
    with pytest.raises(ConfigError, match=match):
        check_command(verb, args, LIMITS, HERE, {"frequencies_hz": [40.0], "current_pp_a": 1.4, "dwell_s": 1.0})


def test_two_commands_that_are_each_fine_cannot_add_up_to_too_much() -> None:
    _, p = check_command("set_excitation", {"current_pp_a": 3.0}, LIMITS, HERE)  # 1.5 A peak: fine
    assert p.peak_a == 1.5
    with pytest.raises(ConfigError, match=r"1\.9 A exceeds"):  # then 0.4 A offset: 1.9 A peak
        check_command("set_excitation", {"offset_a": 0.4}, LIMITS, p)
    ok, q = check_command("set_excitation", {"offset_a": -0.3}, LIMITS, p)  # 1.8 A: the limit itself
    assert ok == {"offset_a": -0.3} and q.peak_a == pytest.approx(1.8)


def test_the_commanded_point_is_the_operating_point_the_blocks_carry() -> None:
    """One type for an operating point (issue 11): a command leads to a messages.OperatingPoint,
    with the fields no command sets (output, table) carried through, and its peak current."""
    start = OperatingPoint(320.0, 1.4, 0.0, output_on=False, table=3)
    _, p = check_command("set_excitation", {"current_pp_a": 2.0, "offset_a": -0.6}, LIMITS, start)
    assert type(p) is OperatingPoint and p == OperatingPoint(320.0, 2.0, -0.6, output_on=False, table=3)
    assert p.peak_a == pytest.approx(0.6 + 2.0 / 2)
    _, q = check_command("start_sweep", {"frequencies_hz": [40.0, 80.0], "current_pp_a": 1.0, "dwell_s": 1.0},
                         LIMITS, p)
    assert q == OperatingPoint(80.0, 1.0, -0.6, output_on=False, table=3)  # the last point; the offset stays


def test_each_argument_is_checked_by_its_key_of_the_one_validator() -> None:
    """The per-argument rules are the Keys of ARGUMENTS (hystbench.config.schema, which checks every
    TOML file): type, finiteness, range and unit come from there; the verbs take what they list."""
    assert {verb: set(keys) for verb, keys in ARGUMENTS.items()} == {
        "start_sweep": {"frequencies_hz", "current_pp_a", "dwell_s"}, "stop_sweep": set(),
        "set_excitation": {"frequency_hz", "current_pp_a", "offset_a"}, "output": {"on"}, "clear_fault": set()}
    assert COMMANDS == {verb: tuple(keys) for verb, keys in ARGUMENTS.items()}
    sweep = {"frequencies_hz": [40.0], "current_pp_a": 1.4, "dwell_s": 1.0}
    ok, _ = check_command("start_sweep", {"dwell_s": 86_400}, LIMITS, HERE, sweep)  # a day at one point: the most
    assert ok["dwell_s"] == 86_400.0 and type(ok["dwell_s"]) is float
    with pytest.raises(ConfigError, match=r"^start_sweep: dwell_s must be in \(0, 86400\] s, got 86400\.5$"):
        check_command("start_sweep", {"dwell_s": 86_400.5}, LIMITS, HERE, sweep)
    for verb in ("set_excitation", "start_sweep"):
        with pytest.raises(ConfigError, match=rf"^{verb}: current_pp_a must be >= 0 A, got -0\.001$"):
            check_command(verb, {"current_pp_a": -0.001}, LIMITS, HERE, sweep)
    with pytest.raises(ConfigError, match=r"^start_sweep: dwell_s must be a finite number, got 1000"):
        check_command("start_sweep", {"dwell_s": 10**400}, LIMITS, HERE, sweep)  # JSON integers have no bound
    with pytest.raises(ConfigError, match=r"^set_excitation: offset_a must be a finite number, got -inf$"):
        check_command("set_excitation", {"offset_a": -math.inf}, LIMITS, HERE)


def test_the_sweep_fills_in_its_defaults_and_checks_them() -> None:
    ok, p = check_command("start_sweep", {}, LIMITS, HERE, {"frequencies_hz": [40, 80], "current_pp_a": 1, "dwell_s": 2})
    assert ok == {"frequencies_hz": [40.0, 80.0], "current_pp_a": 1.0, "dwell_s": 2.0} and p.frequency_hz == 80.0


def test_a_sweep_whose_dwell_measures_nothing_at_some_point_is_refused() -> None:
    """A point is played for dwell_s: fewer whole periods there than the estimator skips and fits, and
    the sweep drives the coil for nothing at that point (1 ns at 40 Hz was accepted)."""
    need = (12.0, "[estimation] settle_periods 2 + periods 10")
    sweep = {"frequencies_hz": [40.0, 320.0], "current_pp_a": 1.0, "dwell_s": 1.0}
    with pytest.raises(ConfigError, match=r"^start_sweep: dwell_s = 1e-09 s is too short at 40 Hz, where a point "
                                          r"needs 12 periods \(\[estimation\] settle_periods 2 \+ periods 10\), 0\.3 s: "
                                          r"give dwell_s >= 0\.3 s, or leave that frequency out$"):
        check_command("start_sweep", {"dwell_s": 1e-9}, LIMITS, HERE, sweep, need)
    with pytest.raises(ConfigError, match="too short at 40 Hz"):  # the lowest frequency needs the longest
        check_command("start_sweep", {"dwell_s": 0.29}, LIMITS, HERE, sweep, need)
    ok, _ = check_command("start_sweep", {"dwell_s": 0.3}, LIMITS, HERE, sweep, need)  # 12 periods exactly
    assert ok["dwell_s"] == 0.3
    ok, _ = check_command("start_sweep", {"frequencies_hz": [320.0], "dwell_s": 0.0375}, LIMITS, HERE, sweep, need)
    assert ok["frequencies_hz"] == [320.0]


# --- random commands at a running service --------------------------------------------------------
_KEYS = st.sampled_from(["frequency_hz", "current_pp_a", "offset_a", "on", "frequencies_hz", "dwell_s"]) | st.text(max_size=8)
_PLAUSIBLE = st.one_of(st.floats(1.0, 2000.0), st.floats(0.0, 5.0), st.floats(0.01, 0.5), st.booleans(),
                       st.lists(st.floats(1.0, 2000.0), min_size=1, max_size=3))
_WILD = st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.integers(-10**400, 10**400), st.none(),
                  st.text(max_size=8), st.lists(st.floats(allow_nan=True), max_size=4),
                  st.dictionaries(st.text(max_size=3), st.integers(), max_size=2))
_ARGS = st.dictionaries(_KEYS, _PLAUSIBLE | _WILD, max_size=4)
_VERBS = st.sampled_from(list(COMMANDS)) | st.text(max_size=12)


def _service(tmp_path: Path, port: int | None = None) -> BenchService:
    """The simulated voice coil (its simulation converges over the bench's whole current range,
    unlike the magnet-biased E-core's, whose iron saturates from ~2 A-pp: a fault, tested in
    test_daemon.py)."""
    toml = tmp_path / "daemon.toml"
    zenoh = f'listen = ["tcp/127.0.0.1:{port}"]' if port else "enabled = false"
    toml.write_text(f'[daemon]\nbench = "fuzz"\nlog_dir = "{tmp_path.as_posix()}"\n'
                    f'[source]\nkind = "sim"\nrig = "voicecoil_ferrite"\n'
                    f'[recording]\nidle_raw = "full"\n[zenoh]\n{zenoh}\n'
                    f'[sweep]\nfrequencies_hz = [160.0, 320.0]\ndwell_s = 0.08\n', encoding="utf-8")  # 12.8 periods at 160 Hz
    return BenchService(load_daemon_config(toml)).start()


def _peak_current(paths: list[Path]) -> float:
    return max(float(np.max(np.abs(b.channels["current_A"]))) for p in paths for b in iter_blocks(p) if b.n)


def test_random_commands_never_end_the_service_nor_exceed_the_limit(tmp_path: Path) -> None:
    svc = _service(tmp_path)
    answered = {"ok": 0, "refused": 0}
    try:
        @settings(max_examples=50, deadline=None, suppress_health_check=list(HealthCheck))
        @given(verb=_VERBS, args=_ARGS | _WILD)
        def one(verb, args) -> None:
            try:
                svc.command(verb, args)
                answered["ok"] += 1
            except BenchError:  # a refusal, with its reason; anything else fails the test
                answered["refused"] += 1
            assert svc.point.peak_a <= svc.limits.max_current_a * (1 + 1e-9)
            assert svc.state in ("running", "sweeping") and svc.pipeline.error is None

        one()
        most = 2 * svc.limits.max_current_a  # the most the bench allows: 1.8 A trip less 5 %, peak to peak
        assert most == pytest.approx(2 * 1.8 * 0.95)
        seen = threading.Event()
        svc.pipeline.listeners.append(lambda topic, obj: seen.set() if topic == "/estimate" and obj[
            "nominal_frequency_hz"] == 320.0 and obj["current_pp_a"] == most else None)
        for verb, args in (("stop_sweep", {}), ("set_excitation", {"frequency_hz": 320.0, "current_pp_a": most,
                                                                   "offset_a": 0.0}),
                           ("output", {"on": True})):  # driven for sure
            svc.command(verb, args)
        assert seen.wait(30.0)  # the pipeline still runs: an estimate at the most came after all of it
        health = svc.health()
        assert health["state"] in ("running", "sweeping") and health["pipeline_error"] is None
        assert health["faults"] == 0  # nothing accepted made a stage fail
    finally:
        paths = svc.stop()
    assert answered["ok"] + answered["refused"] >= 50 and answered["refused"] > 0
    peak = _peak_current(paths)
    assert 1.6 < peak < 1.8, peak  # driven at the most; never at the amplifier's 1.8 A trip level


def test_random_payloads_over_zenoh_are_each_answered(tmp_path: Path) -> None:
    port = free_port()
    svc = _service(tmp_path, port)
    s = open_session(load_zenoh_config(peer_config(connect=[f"tcp/127.0.0.1:{port}"])))
    try:
        @settings(max_examples=15, deadline=None, suppress_health_check=list(HealthCheck))
        @given(verb=st.sampled_from(list(COMMANDS)) | st.from_regex(r"[a-z_]{1,10}", fullmatch=True),
               payload=st.one_of(_ARGS.map(lambda a: json.dumps(a, default=str).encode()),
                                 st.binary(max_size=20), st.just(b'{"frequency_hz": NaN}'),
                                 st.just(b'{"current_pp_a": 1e999}'), st.just(b"[" * 5000)))
        def one(verb, payload) -> None:
            replies = list(s.get(key("fuzz", "cmd", verb), payload=payload, timeout=10.0))
            assert len(replies) == 1  # answered: ok, or refused with a reason
            r = replies[0]
            body = json.loads((r.ok or r.err).payload.to_bytes())
            assert body["ok"] is (r.ok is not None) and (body["ok"] or body["error"])

        one()
        health = list(s.get(key("fuzz", "health"), timeout=10.0))
        assert json.loads(health[0].ok.payload.to_bytes())["state"] in ("running", "sweeping")
        assert svc.pipeline.error is None
    finally:
        s.close()
        svc.stop()
