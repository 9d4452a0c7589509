"""What the golden recording's tests share (data/ecore_golden.npz, made before the kernels)."""

from __future__ import annotations

import numpy as np
import pytest

from hystbench.physics.instrument import InstrumentModel, bilinear_sos


def _bilinear_instrument(self: InstrumentModel, fs_hz: float, *, core: bool = True) -> np.ndarray:
    return np.vstack([bilinear_sos(b, a, fs_hz, pw) for b, a, pw in self.sections(core=core)])


@pytest.fixture
def golden_instrument(monkeypatch: pytest.MonkeyPatch) -> None:
    """The load cell sampled as the golden's simulator sampled it: every section by the bilinear
    transform.  Since 2026-11-29 the two low-passes are sampled by a compensated hold (physics/
    instrument.hold_sos, tested against the continuous model in tests/physics/test_instrument.py),
    which moves ecore_pm's force by about 7e-5 of itself at 320 Hz: 1 ADC code on 14 % of samples."""
    monkeypatch.setattr(InstrumentModel, "sos", _bilinear_instrument)


@pytest.fixture
def changed_since_golden() -> tuple[str, ...]:
    """Channels changed on purpose since the golden recording: the sense coil's voltage takes the
    iron's share of dphi/dt by a second-order backward difference, no longer a first-order one half a
    sample late (up to 26 ADC codes).  It is held to Faraday's law against the flux instead
    (tests/analysis/test_sense_coil.py), and the numpy path to the kernel's by test_ecore_kernel."""
    return ("sense_V",)
