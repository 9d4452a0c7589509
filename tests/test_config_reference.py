"""docs/config.md is generated from the checkers' own schemas: a stale file fails here, every key of
every file is documented, and every documented numeric range is the one enforced (just outside:
refused naming the file, the table and the key; on an inclusive bound: accepted), for the daemon
file, the bench file, the rig presets (their effects included) and the material files."""

from __future__ import annotations

import json
import math
import tomllib
from pathlib import Path
from typing import Any

import pytest

from hystbench.config import CONFIG_DIR, load_material, load_rig
from hystbench.config.effects import CATALOGUE
from hystbench.config.presets import MATERIAL_SCHEMA, RIG_SCHEMAS
from hystbench.config.schema import Key, tables
from hystbench.drivers.protocols.bench_config import DEFAULT_BENCH, SCHEMA as BENCH, load_bench_config
from hystbench.errors import ConfigError
from hystbench.reports.config_reference import DOC_PATH, main, render
from hystbench.service.daemon_config import SCHEMA as DAEMON, load_daemon_config


def test_committed_reference_is_the_generated_one() -> None:
    assert DOC_PATH.read_text(encoding="utf-8") == render(), \
        "docs/config.md is stale: run python -m hystbench.reports.config_reference"


def test_check_mode_reports_a_stale_file(tmp_path: Path, capsys) -> None:
    stale = tmp_path / "config.md"
    stale.write_text("# old\n", encoding="utf-8")
    assert main([str(stale), "--check"]) == 1
    assert "out of date" in capsys.readouterr().err
    assert main([str(stale)]) == 0 and main([str(stale), "--check"]) == 0


def _block(text: str, title: str) -> str:
    return text.split(f"### {title}", 1)[1].split("###", 1)[0]


def test_reference_names_every_key_of_every_file() -> None:
    text = render()
    schemas = [DAEMON, BENCH, MATERIAL_SCHEMA, *RIG_SCHEMAS.values()]
    for schema in schemas:
        for path, keys, array in tables(schema):
            if path and not path.startswith("effects"):
                title = f"`[[{path}]]`" if array else f"`[{path}]`"
                assert any(all(f"| `{k}` |" in block for k in keys)
                           for block in text.split(f"### {title}")[1:]), path
    for e in CATALOGUE.values():  # every effect, with each parameter's unit and range
        block = _block(text, f"`[effects.{e.name}]`")
        for k, p in e.params.items():
            row = f"| `{k}` | {p.type_text()} | {p.unit} | {p.range_text()} |"
            assert row in block.replace("\\<", "<"), (e.name, k)
    assert "| `learning_gain` | number |  | in (0, 1.5] | `0.8` |" in text
    assert "| `remanence_t` | number | T | > 0 | (required) |" in text  # a magnet's Br: a rig preset key


def _outside(k: Key) -> list:
    """Values just outside the documented range, computed from the bounds (not from the checker)."""
    out: list[Any] = []
    if k.gt is not None:
        out.append(k.gt)  # the exclusive bound itself
    if k.ge is not None:
        out.append(k.ge - 1 if k.kind is int else k.ge - 0.5)
    if k.lt is not None:
        out.append(k.lt)
    if k.le is not None:
        out.append(k.le + 1 if k.kind is int else k.le * 1.5 + 0.5)
    if k.whole:
        out.append((k.ge if k.ge is not None else 0) + 0.5)  # in range, but not whole
    return out


def _inclusive_bounds(k: Key) -> list:
    return [k.kind(b) if k.kind is int else b for b in (k.ge, k.le) if b is not None]


def _cases(schema: dict) -> list[tuple[str, str, Key]]:
    return [(path, name, k) for path, keys, array in tables(schema) if not array
            for name, k in keys.items() if _outside(k)]


def _dump(data: dict) -> str:
    """A dict back to TOML: tables of scalars, sub-tables and arrays of tables, empty tables inline."""
    lines: list[str] = []

    def value(v: Any) -> str:
        return "{}" if isinstance(v, dict) else "nan" if isinstance(v, float) and math.isnan(v) else json.dumps(v)

    def table(name: str, body: dict, header: str) -> None:
        lines.append(header)
        subs = {}
        for key, v in body.items():
            if (isinstance(v, dict) and v) or (isinstance(v, list) and v and isinstance(v[0], dict)):
                subs[key] = v
            else:
                lines.append(f"{key} = {value(v)}")
        for key, v in subs.items():
            for item in (v if isinstance(v, list) else [v]):
                table(f"{name}.{key}", item, f"[[{name}.{key}]]" if isinstance(v, list) else f"[{name}.{key}]")

    top = {k: v for k, v in data.items() if not isinstance(v, dict)}
    lines += [f"{k} = {value(v)}" for k, v in top.items()]
    for name, body in data.items():
        if isinstance(body, dict):
            table(name, body, f"[{name}]")
    return "\n".join(lines) + "\n"


def _with(data: dict, table: str, key: str, value: Any) -> dict:
    node = data
    for part in table.split(".") if table else []:
        node = node.setdefault(part, {})
    node[key] = value
    return data


def _refused_naming(load, path: Path, text: str, table: str, name: str, k: Key) -> None:
    path.write_text(text, encoding="utf-8")
    with pytest.raises(ConfigError) as info:
        load(path)
    msg = str(info.value)
    place = f"{path} [{table}] {name}: must be " if table else f"{path} {name}: must be "
    assert msg.startswith(place) and k.range_text() in msg, msg


DAEMON_CASES = _cases(DAEMON)


@pytest.mark.parametrize("section, name, k", DAEMON_CASES, ids=[f"{s}.{n}" for s, n, _ in DAEMON_CASES])
def test_daemon_value_outside_documented_range_is_refused_naming_the_key(tmp_path: Path, section, name, k) -> None:
    cfg = tmp_path / "d.toml"
    for bad in _outside(k):
        _refused_naming(load_daemon_config, cfg, f"[{section}]\n{name} = {json.dumps(bad)}\n", section, name, k)
    for ok in _inclusive_bounds(k):
        cfg.write_text(f"[{section}]\n{name} = {json.dumps(ok)}\n", encoding="utf-8")
        assert load_daemon_config(cfg)[section][name] == ok


def test_daemon_range_examples_from_physics_and_the_compensator() -> None:
    """Spot checks written from the meaning, not from the table: the learning loop's gain is stable
    only in (0, 1.5] (LearningConfig), a compensator current limit below 0 A means nothing (0 takes the bench's)."""
    keys = DAEMON["compensator"].table
    assert (keys["learning_gain"].gt, keys["learning_gain"].le) == (0, 1.5)
    assert keys["current_limit_a"].problem(-0.1) == "must be >= 0"  # 0: the bench's command limit
    assert DAEMON["sweep"].table["current_pp_a"].problem(0.0) is None  # a sweep at 0 A: the zero-current baseline


BENCH_CASES = _cases(BENCH)


@pytest.mark.parametrize("table, name, k", BENCH_CASES, ids=[f"{t}.{n}" for t, n, _ in BENCH_CASES])
def test_bench_value_outside_documented_range_is_refused_naming_the_key(tmp_path: Path, table, name, k) -> None:
    path = tmp_path / "bench.toml"
    # [digitiser] requires its channels: its keys are tried on the shipped bench file that has the table
    base = CONFIG_DIR / "bench_digitiser.toml" if table.startswith("digitiser") else DEFAULT_BENCH
    for bad in _outside(k):
        data = _with(tomllib.loads(base.read_text(encoding="utf-8")), table, name, bad)
        _refused_naming(load_bench_config, path, _dump(data), table, name, k)
    for ok in _inclusive_bounds(k):
        data = _with(tomllib.loads(base.read_text(encoding="utf-8")), table, name, ok)
        if (table, name) == ("current_amplifier.settings", "current_limit_a"):  # a trip level needs a bench limit above it
            data["bench"]["max_current_a"] = max(data["bench"]["max_current_a"], ok)
        path.write_text(_dump(data), encoding="utf-8")
        load_bench_config(path)  # the bound itself is legal


#: A shipped preset of each actuator, with a magnet where the actuator can have one.
_SHIPPED = {"ecore": "ecore_pm", "voicecoil": "voicecoil_ndfeb", "toroid": "toroid"}
RIG_CASES = [(a, t, n, k) for a, schema in RIG_SCHEMAS.items() for t, n, k in _cases(schema)]


@pytest.mark.parametrize("actuator, table, name, k", RIG_CASES, ids=[f"{a}.{t}.{n}" for a, t, n, _ in RIG_CASES])
def test_rig_value_outside_documented_range_is_refused_naming_the_key(tmp_path: Path, actuator, table, name, k) -> None:
    source = CONFIG_DIR / "rigs" / f"{_SHIPPED[actuator]}.toml"
    path = tmp_path / "rig.toml"
    for bad in _outside(k):
        data = _with(tomllib.loads(source.read_text(encoding="utf-8")), table, name, bad)
        _refused_naming(load_rig, path, _dump(data), table, name, k)
    for ok in _inclusive_bounds(k):
        path.write_text(_dump(_with(tomllib.loads(source.read_text(encoding="utf-8")), table, name, ok)),
                        encoding="utf-8")
        assert load_rig(path)[table.split(".")[0]]  # the bound itself is legal


MATERIAL_CASES = _cases(MATERIAL_SCHEMA) + [
    (f"{p}[0]", n, k) for p, keys, array in tables(MATERIAL_SCHEMA) if array for n, k in keys.items() if _outside(k)]


@pytest.mark.parametrize("table, name, k", MATERIAL_CASES, ids=[f"{t}.{n}" for t, n, _ in MATERIAL_CASES])
def test_material_value_outside_documented_range_is_refused_naming_the_key(tmp_path: Path, table, name, k) -> None:
    source = CONFIG_DIR / "materials" / "M330-50A.toml"
    path = tmp_path / "material.toml"
    for bad in _outside(k):
        data = tomllib.loads(source.read_text(encoding="utf-8"))
        parent, _, index = table.partition("[")
        node = data[parent.split(".")[0]][parent.split(".")[1]][int(index[:-1])] if index else None
        if node is not None:
            node[name] = bad
        else:
            _with(data, table, name, bad)
        _refused_naming(load_material, path, _dump(data), table, name, k)
