"""How well a Preisach fitted to a material's LARGEST loop predicts its smaller (minor) loops.

The simulated E-core iron (M330-50A) is fitted to its major loop only -- no minor-loop data of that
steel exist -- so its minor-loop losses are a prediction.  The real M130-27S data has three symmetric
loops (Hm = 17.5, 65, 217 A/m); fitting to the 217 A/m loop alone and predicting the other two
measures the size of that uncertainty: loop energy and loss angle within about +-30 %.  Fitting all
three loops removes most of it, i.e. minor-loop data would improve the M330-50A model.
"""

import math

import pytest

from hystbench.physics import material_fit as mf
from hystbench.physics.hysteresis import PreisachHysteresis

pytestmark = pytest.mark.slow(15)  # ~15 s: handed to a worker before lighter files (tests/conftest.py)

BAND = (0.7, 1.3)  # the claim under test: minor-loop energy (and sin of the loss angle) within +-30 %


@pytest.fixture(scope="module")
def loops():
    return mf.load_loops("M130-27S")  # small to large


@pytest.fixture(scope="module")
def major_only(loops):
    big = max(loops, key=lambda lp: lp.h_max)
    return PreisachHysteresis(mf.fit_material([big], h_max_a_per_m=10000))


def _lag(b, loop):
    # The loops are sampled uniformly in H along a triangular H (each branch includes both tips), so
    # the sample index is time for a triangular-H excitation and the 256 samples are one period.
    return mf.b_lag_behind_h_deg(b, loop.h_a_per_m)


def test_the_major_loop_itself_is_fitted_well(loops, major_only):
    e = mf.loop_error(major_only, loops[-1])  # seen: area x0.998, RMS 0.35 % of Bm
    assert e["area_ratio"] == pytest.approx(1.0, abs=0.05) and e["rms_pct"] < 1.0, e


@pytest.mark.parametrize("i", [0, 1])
def test_minor_loop_energy_is_predicted_within_30_percent(loops, major_only, i):
    """Energy per cycle of the unseen smaller loops.  Seen: Hm=17.5 x1.12, Hm=65 x0.85."""
    e = mf.loop_error(major_only, loops[i])
    assert BAND[0] <= e["area_ratio"] <= BAND[1], (loops[i].label, e)


@pytest.mark.parametrize("i", [0, 1])
def test_minor_loop_loss_angle_is_predicted(loops, major_only, i):
    """First-harmonic lag of B behind H, predicted vs measured.  Seen (measured -> predicted):
    Hm=17.5: 30.6 -> 37.5 deg; Hm=65: 13.6 -> 12.4 deg (Hm=217: 6.10 -> 6.10).

    Tolerance: the energy per cycle is ~ pi H1 B1 sin(lag), so the +-30 % energy claim is a +-30 %
    claim on sin(lag), not a fixed number of degrees: at the 17.5 A/m loop's 30 deg it allows
    about -10/+11 deg, at the 65 A/m loop's 14 deg about -4/+4 deg.  The 7 deg miss on the smallest
    loop is real (its predicted loop is too fat and its B shape is off by 14 % RMS)."""
    lp = loops[i]
    measured, predicted = _lag(lp.b_t, lp), _lag(mf.model_loop(major_only, lp), lp)
    assert 0.0 < predicted < 90.0
    ratio = math.sin(math.radians(predicted)) / math.sin(math.radians(measured))
    assert BAND[0] <= ratio <= BAND[1], (lp.label, measured, predicted)


def test_minor_loop_data_improve_the_model(loops, major_only):
    """One parameter set fitted to all three loops beats the major-loop-only prediction on the
    smallest loop.  Seen: RMS 1.0 % vs 13.8 % of Bm, lag 30.5 vs measured 30.6 deg.  The 2 deg
    allowance is the lag error a 5 % energy error makes at 30 deg (d lag = 0.05 tan(lag) rad)."""
    small = loops[0]
    all_loops = PreisachHysteresis(mf.fit_material(loops, h_max_a_per_m=10000))
    e_all, e_major = mf.loop_error(all_loops, small), mf.loop_error(major_only, small)
    assert 2 * e_all["rms_pct"] < e_major["rms_pct"], (e_all, e_major)
    assert e_all["area_ratio"] == pytest.approx(1.0, abs=0.05), e_all
    assert _lag(mf.model_loop(all_loops, small), small) == pytest.approx(_lag(small.b_t, small), abs=2.0)
