"""The phase-delay model (paper Eq. 6) against Eq. 1 and closed forms."""

import numpy as np
import pytest

from hystbench.config import load_rig
from hystbench.physics import presets
from hystbench.physics.phase_delay_model import PhaseDelayModel, delay_periodic, delay_record

COEF = (172.0, 68.0, 4.0)  # k0 (N), k1 (N/A), k2 (N/A^2): an E-core with magnet


def test_theta_zero_is_eq1_of_the_mec():
    mec = presets.ecore_mec(load_rig("ecore_pm"), linear_iron=True)
    model = PhaseDelayModel.from_mec(mec, [40.0, 480.0], [0.0, 0.0])
    i = 0.7 * np.sin(2 * np.pi * np.arange(400) / 400) + 0.05
    assert model.force_period(i, 320.0) == pytest.approx(mec.force(i), rel=1e-12, abs=1e-9)
    assert PhaseDelayModel.non_hysteretic(COEF).force_period(i, 123.0) == pytest.approx(
        COEF[0] + COEF[1] * i + COEF[2] * i * i, rel=1e-12)


def test_eq6_delays_the_current_by_theta_over_omega():
    theta = np.radians(2.0)
    model = PhaseDelayModel.from_phases(COEF, [320.0], [theta])
    n = 1000
    phase = np.arange(n) / n
    i = 0.7 * np.sin(2 * np.pi * phase)
    expected = model.static_force(0.7 * np.sin(2 * np.pi * phase - theta))
    assert model.force_period(i, 320.0) == pytest.approx(expected, abs=1e-9)
    assert model.force_sine(phase / 320.0, 0.7, 320.0) == pytest.approx(expected, abs=1e-9)


def test_record_form_agrees_with_the_period_form():
    model = PhaseDelayModel.from_phases(COEF, [100.0, 400.0], [0.01, 0.04])
    fs, f = 100_000.0, 250.0
    t = np.arange(2000) / fs  # 5 periods
    i = 0.6 * np.sin(2 * np.pi * f * t) + 0.1 * np.sin(6 * np.pi * f * t)
    got = model.force(i, fs, f)
    want = model.static_force(0.6 * np.sin(2 * np.pi * f * t - model.theta(f))
                              + 0.1 * np.sin(3 * (2 * np.pi * f * t - model.theta(f))))
    assert got == pytest.approx(want, abs=2e-6 * np.ptp(want))


def test_theta_interpolates_holds_below_and_extends_above():
    model = PhaseDelayModel.from_phases(COEF, [40.0, 80.0, 320.0], [0.01, 0.012, 0.03])
    assert model.theta(60.0) == pytest.approx(0.011)
    assert model.theta(10.0) == pytest.approx(0.01)  # rate-independent part held
    assert model.theta(560.0) == pytest.approx(0.03 + 0.018 / 240 * 240)  # last segment continued
    assert model.delay_s(320.0) == pytest.approx(0.03 / (2 * np.pi * 320.0))


def test_several_amplitudes_at_one_frequency_are_averaged_by_weight():
    model = PhaseDelayModel.from_delays(COEF, [320.0, 320.0, 40.0], [10e-6, 12e-6, 30e-6], [1e-7, 2e-7, 1e-7])
    w = 2 * np.pi * 320.0
    expected = (10e-6 / 1e-14 + 12e-6 / 4e-14) / (1 / 1e-14 + 1 / 4e-14) * w
    assert model.frequency_hz.tolist() == [40.0, 320.0]
    assert model.theta(320.0) == pytest.approx(expected)


def test_delay_periodic_shifts_a_multi_harmonic_signal_exactly():
    n = 64
    p = np.arange(n) / n
    x = np.cos(2 * np.pi * p) + 0.3 * np.sin(2 * np.pi * 5 * p) + 0.2 * np.cos(np.pi * n * p)  # incl. Nyquist
    d = 0.1234
    want = (np.cos(2 * np.pi * (p - d)) + 0.3 * np.sin(2 * np.pi * 5 * (p - d))
            + 0.2 * np.cos(np.pi * n * p) * np.cos(np.pi * n * d))
    assert delay_periodic(x, d) == pytest.approx(want, abs=1e-12)


def test_bad_arguments_are_named():
    with pytest.raises(ValueError, match="frequency_hz"):
        PhaseDelayModel.from_phases(COEF, [0.0], [0.1])
    with pytest.raises(ValueError, match="one length"):
        PhaseDelayModel.from_phases(COEF, [40.0, 80.0], [0.1])
    with pytest.raises(ValueError, match="too short"):
        delay_record(np.ones(10), 1000.0, 1e-3, 50.0)
