"""Instruments are built from the ``drivers.BACKENDS`` table (issue 11): a bench-file table name
gives the driver class (imported only when asked for), and the class builds itself from its table.
Adding an instrument is one row and one class; the bench has no branch per instrument name."""

import subprocess
import sys
import textwrap
from dataclasses import replace

import pytest

from hystbench import drivers
from hystbench.config import CONFIG_DIR
from hystbench.drivers.base import Backoff, Instrument
from hystbench.drivers.bench import build_instruments
from hystbench.drivers.protocols.bench_config import INSTRUMENTS, load_bench_config
from hystbench.drivers.safety import CurrentBudget
from hystbench.errors import ConfigError


def test_every_instrument_of_a_bench_file_has_a_row_naming_a_driver_of_that_kind():
    assert set(drivers.BACKENDS) == set(INSTRUMENTS)
    for name in INSTRUMENTS:
        cls = drivers.instrument_class(name)
        assert issubclass(cls, Instrument) and cls.kind == name
        assert (cls.__module__, cls.__name__) == drivers.BACKENDS[name]


def test_an_unknown_instrument_is_refused_naming_it_and_the_known_ones():
    with pytest.raises(ConfigError, match=r"no driver for instrument 'oscilloscope'; known: signal_generator"):
        drivers.instrument_class("oscilloscope")


def test_a_driver_module_is_imported_only_when_its_instrument_is_asked_for():
    code = textwrap.dedent("""
        import sys
        import hystbench.drivers as d
        d.instrument_class("signal_generator")
        assert "hystbench.drivers.flux_integrator" not in sys.modules and "can" not in sys.modules
        d.instrument_class("flux_integrator")
        assert "hystbench.drivers.flux_integrator" in sys.modules
    """)
    subprocess.run([sys.executable, "-c", code], check=True, timeout=120)


def test_each_driver_takes_the_bench_files_deadline_backoff_and_sample_rate():
    cfg = load_bench_config(CONFIG_DIR / "bench_hardware.toml")
    slow = replace(cfg.instruments["flux_integrator"], timeout_s=cfg.timeout_s + 0.25)  # its own deadline
    cfg = replace(cfg, instruments={**cfg.instruments, "flux_integrator": slow})
    built = build_instruments(cfg, CurrentBudget(cfg.max_current_a, 0.5))
    assert list(built) == list(cfg.instruments)
    for name, inst in built.items():
        assert type(inst) is drivers.instrument_class(name) and inst.name == name
        assert inst.timeout_s == (cfg.timeout_s + 0.25 if name == "flux_integrator" else cfg.timeout_s)
        assert inst.backoff == Backoff(**cfg.backoff) and inst.fs_hz == cfg.fs_hz
    assert built["signal_generator"].budget is built["current_amplifier"].budget  # one budget for the current


def test_a_new_row_is_all_the_bench_needs_to_build_another_class(tmp_path, monkeypatch):
    """A site's own charge amplifier driver: one module, one row; build_instruments uses it."""
    (tmp_path / "site_drivers.py").write_text(textwrap.dedent("""
        from hystbench.drivers.charge_amplifier import ChargeAmplifier

        class SiteChargeAmplifier(ChargeAmplifier):
            @classmethod
            def from_config(cls, config, bench, budget):
                inst = super().from_config(config, bench, budget)
                inst.built_from = config
                return inst
    """))
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setitem(drivers.BACKENDS, "charge_amplifier", ("site_drivers", "SiteChargeAmplifier"))
    cfg = load_bench_config(CONFIG_DIR / "bench_hardware.toml")
    built = build_instruments(cfg, CurrentBudget(cfg.max_current_a, 0.5))
    amp = built["charge_amplifier"]
    assert type(amp).__name__ == "SiteChargeAmplifier" and amp.built_from is cfg.instruments["charge_amplifier"]
    assert amp.link.url == cfg.instruments["charge_amplifier"].options["url"]


def test_an_emulated_bench_without_addresses_names_the_table_and_what_to_do():
    cfg = load_bench_config()  # the shipped file: every instrument emulated, addresses not resolved
    with pytest.raises(ConfigError, match=r"\[signal_generator\]: no url \(start the emulators or set one\)"):
        build_instruments(cfg, CurrentBudget(cfg.max_current_a, 0.5))
