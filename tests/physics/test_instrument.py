"""Instrument model against the paper (Figs. 8-9) and the textbook 2nd-order phase."""

import numpy as np
import pytest
from scipy import signal

from hystbench.physics.instrument import InstrumentModel


def textbook_phase_deg(f, fn, zeta):
    r = f / fn
    return -np.degrees(np.arctan2(2 * zeta * r, 1 - r * r))


def test_phase_at_320_hz_is_the_papers_1_28_degrees():
    m = InstrumentModel()  # fn 4.45 kHz, zeta 0.012; f0 31 kHz, zeta 1 (paper Sec. IV C)
    expected = textbook_phase_deg(320, 4450, 0.012) + textbook_phase_deg(320, 31000, 1.0)
    assert m.phase_deg(320.0) == pytest.approx(expected, abs=1e-9)
    assert m.phase_deg(320.0) == pytest.approx(-1.28, abs=0.01)  # "about 1.28 degrees"


def test_charge_amplifier_dominates_at_low_frequency_and_mechanics_at_resonance():
    # Paper Fig. 9: the LPF dominates low frequencies; the mechanical phase drops 180 deg at fn.
    mech = InstrumentModel(f0_hz=1e12)
    assert abs(mech.phase_deg(320.0)) < abs(InstrumentModel().phase_deg(320.0)) / 5
    assert mech.phase_deg(4450.0) == pytest.approx(-90.0, abs=1e-6)
    assert mech.phase_deg(9000.0) < -175.0


@pytest.mark.parametrize("fs", [100_000.0, 200_000.0])
def test_sampled_model_keeps_in_band_phase_and_the_resonance(fs):
    m = InstrumentModel()
    sos = m.sos(fs)
    _, h = signal.sosfreqz(sos, worN=np.array([40.0, 320.0, 480.0]), fs=fs)
    assert np.degrees(np.angle(h)) == pytest.approx(m.phase_deg(np.array([40.0, 320.0, 480.0])), abs=2e-3)
    f = np.linspace(4000, 4900, 901)
    _, h = signal.sosfreqz(sos, worN=f, fs=fs)
    assert f[np.argmax(abs(h))] == pytest.approx(4450.0, abs=5.0)


def test_delay_is_positive_and_about_11_microseconds_at_320_hz():
    d = InstrumentModel().delay_s(320.0)
    assert d == pytest.approx(np.radians(1.282) / (2 * np.pi * 320), rel=1e-3)


def test_frame_mode_is_local():
    plain = InstrumentModel()
    moded = InstrumentModel(frame_modes=((850.0, 0.02, 0.024),))
    assert abs(moded.frequency_response(850.0) / plain.frequency_response(850.0)) == pytest.approx(1.2, rel=1e-9)
    # below the mode, r = 320/850: the pair shifts the phase by atan(2 zz r/(1-r^2)) - atan(2 zp r/(1-r^2))
    r = 320 / 850
    expected = np.degrees(np.arctan(2 * 0.024 * r / (1 - r * r)) - np.arctan(2 * 0.02 * r / (1 - r * r)))
    assert moded.phase_deg(320.0) - plain.phase_deg(320.0) == pytest.approx(expected, abs=1e-9)
    assert moded.phase_deg(3000.0) - plain.phase_deg(3000.0) == pytest.approx(0.0, abs=0.2)


def test_a_split_mode_steps_the_gain_across_it():
    """A frame's two masses: the anti-resonance apart from the resonance; unity gain far below, the
    ratio of the two frequencies squared far above (the mass line), a peak then a dip between."""
    plain = InstrumentModel()
    split = InstrumentModel(frame_modes=((850.0, 0.02, 0.02, 900.0),))
    ratio = lambda f: abs(split.frequency_response(f) / plain.frequency_response(f))  # noqa: E731
    assert ratio(5.0) == pytest.approx(1.0, abs=1e-4)
    assert ratio(40_000.0) == pytest.approx((850.0 / 900.0) ** 2, rel=1e-3)
    assert ratio(840.0) > 1.5 and ratio(910.0) < 0.5  # the peak below, the anti-resonance above
