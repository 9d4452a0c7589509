"""docs/config.md is generated from the checkers' own tables: a stale file fails here, and every
documented numeric range is the one the checkers enforce (just outside: refused naming the key;
on an inclusive bound: accepted)."""

import json
import tomllib
from pathlib import Path

import pytest

from hystbench.acquisition.daemon import DEFAULTS, load_daemon_config
from hystbench.config_reference import DOC_PATH, main, render
from hystbench.drivers.protocols.bench_config import DEFAULT_BENCH, SCHEMA, SETTINGS, load_bench_config
from hystbench.errors import ConfigError


def test_committed_reference_is_the_generated_one() -> None:
    assert DOC_PATH.read_text(encoding="utf-8") == render(), \
        "docs/config.md is stale: run python -m hystbench.config_reference"


def test_check_mode_reports_a_stale_file(tmp_path: Path, capsys) -> None:
    stale = tmp_path / "config.md"
    stale.write_text("# old\n", encoding="utf-8")
    assert main([str(stale), "--check"]) == 1
    assert "out of date" in capsys.readouterr().err
    assert main([str(stale)]) == 0 and main([str(stale), "--check"]) == 0


def test_reference_names_every_key_of_both_files() -> None:
    text = render()
    for section, keys in DEFAULTS.items():
        block = text.split(f"### `[{section}]`", 1)[1].split("###", 1)[0]
        assert all(f"| `{k}` |" in block for k in keys), section
    for table in ("bench", "bench.backoff", "sim", "signal_generator", "signal_generator.settings",
                  "current_amplifier.settings", "charge_amplifier.settings", "flux_integrator.settings"):
        assert f"### `[{table}]`" in text
    assert "| `learning_gain` | number |  | in (0, 1.5] | `0.8` |" in text


def _outside(k) -> list:
    """Values just outside the documented range, computed from the bounds (not from the checker)."""
    out = []
    if k.gt is not None:
        out.append(k.gt)  # the exclusive bound itself
    if k.ge is not None:
        out.append(k.ge - 1 if k.kind is int else k.ge - 0.5)
    if k.le is not None:
        out.append(k.le + 1 if k.kind is int else k.le * 1.5 + 0.5)
    return out


def _inclusive_bounds(k) -> list:
    return [b for b in (k.ge, k.le) if b is not None]


def _toml(v) -> str:
    return json.dumps(v)


DAEMON_CASES = [(s, name, k) for s, keys in DEFAULTS.items() for name, k in keys.items() if _outside(k)]


@pytest.mark.parametrize("section, name, k", DAEMON_CASES, ids=[f"{s}.{n}" for s, n, _ in DAEMON_CASES])
def test_daemon_value_outside_documented_range_is_refused_naming_the_key(tmp_path: Path, section, name, k) -> None:
    cfg = tmp_path / "d.toml"
    for bad in _outside(k):
        cfg.write_text(f"[{section}]\n{name} = {_toml(bad)}\n", encoding="utf-8")
        with pytest.raises(ConfigError) as info:
            load_daemon_config(cfg)
        msg = str(info.value)
        assert str(cfg) in msg and f"[{section}] {name}: must be {k.range_text()}" in msg
    for ok in _inclusive_bounds(k):
        cfg.write_text(f"[{section}]\n{name} = {_toml(k.kind(ok) if k.kind is int else ok)}\n", encoding="utf-8")
        assert load_daemon_config(cfg)[section][name] == ok


def test_daemon_range_examples_from_physics_and_the_compensator() -> None:
    """Spot checks written from the meaning, not from the table: the learning loop's gain is stable
    only in (0, 1.5] (LearningConfig), a compensator current limit of 0 A could never drive."""
    assert (DEFAULTS["compensator"]["learning_gain"].gt, DEFAULTS["compensator"]["learning_gain"].le) == (0, 1.5)
    assert DEFAULTS["compensator"]["current_limit_a"].problem(0.0) == "must be > 0"
    assert DEFAULTS["sweep"]["current_pp_a"].problem(0.0) is None  # a sweep at 0 A: the zero-current baseline


def _dump(data: dict) -> str:
    """A bench file's dict back to TOML (tables of scalars, inline empty tables, sub-tables)."""
    lines = []

    def table(name: str, body: dict) -> None:
        lines.append(f"[{name}]")
        subs = {}
        for key, v in body.items():
            if isinstance(v, dict) and v:
                subs[key] = v
            else:
                lines.append(f"{key} = {'{}' if isinstance(v, dict) else json.dumps(v)}")
        for key, v in subs.items():
            table(f"{name}.{key}", v)

    for name, body in data.items():
        table(name, body)
    return "\n".join(lines) + "\n"


def _bench_with(table: str, key: str, value) -> dict:
    data = tomllib.loads(DEFAULT_BENCH.read_text(encoding="utf-8"))
    node = data
    for part in table.split("."):
        node = node.setdefault(part, {})
    node[key] = value
    return data


BENCH_CASES = ([(t, n, k) for t, keys in SCHEMA.items() for n, k in keys.items() if _outside(k)]
               + [(f"{i}.settings", n, k) for i, keys in SETTINGS.items() for n, k in keys.items() if _outside(k)])


@pytest.mark.parametrize("table, name, k", BENCH_CASES, ids=[f"{t}.{n}" for t, n, _ in BENCH_CASES])
def test_bench_value_outside_documented_range_is_refused_naming_the_key(tmp_path: Path, table, name, k) -> None:
    path = tmp_path / "bench.toml"
    for bad in _outside(k):
        path.write_text(_dump(_bench_with(table, name, bad)), encoding="utf-8")
        with pytest.raises(ConfigError) as info:
            load_bench_config(path)
        msg = str(info.value)
        assert str(path) in msg and f"[{table}]" in msg and f"key {name!r}" in msg
    for ok in _inclusive_bounds(k):
        path.write_text(_dump(_bench_with(table, name, int(ok) if k.kind is int else ok)), encoding="utf-8")
        load_bench_config(path)  # the bound itself is legal
