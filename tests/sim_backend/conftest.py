"""What the golden recording's tests share (data/ecore_golden.npz, made before the kernels)."""

from __future__ import annotations

from typing import Callable

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


def _moved_by_a_smooth_curve(x: np.ndarray, ref: np.ndarray, lsb: float | None = None) -> None:
    """The sense voltage moved by the iron's dphi/dt taken half a sample earlier: a smooth curve, up to
    26 ADC codes, while its noise and its ADC are the golden's.  With the ADC (``lsb``), from one sample to
    the next the change moves by 8 codes at most (measured), where the noise moves a code by 210 rms: a
    noise drawn anew or a step of another size would break it.  Without (the quiet runs), the change is
    at most 8.7e-4 of the channel's range (measured)."""
    if lsb is None:
        assert np.max(np.abs(x - ref)) <= 2e-3 * np.ptp(ref)
    else:
        change = np.round(x / lsb) - ref
        assert np.max(np.abs(np.diff(change))) <= 12 and np.max(np.abs(change)) <= 40


@pytest.fixture
def changed_since_golden() -> dict[str, Callable[..., None]]:
    """Channels changed on purpose since the golden recording, each with what holds of its change: the
    sense coil's voltage takes the iron's share of dphi/dt by a second-order backward difference, no
    longer a first-order one half a sample late (up to 26 ADC codes).  Its value is held to Faraday's
    law against the flux (tests/analysis/test_sense_coil.py), the numpy path to the kernel's by
    test_ecore_kernel, and its noise and ADC chain to the golden's here."""
    return {"sense_V": _moved_by_a_smooth_curve}
