"""The demo's current-force loops are the one synchronous average at the true frequency.

Before, the demo averaged at the nominal frequency on whole samples (a third averager): with the
generator 25 ppm off and 312.5 samples per period it missed this test's force by 0.55 N of 80 N.
"""

import numpy as np

from hystbench.formats.recording import Recording
from hystbench.reports import demo


def test_loop_follows_the_waveform_at_the_true_frequency():
    fs, nominal = 100_000.0, 320.0
    f = nominal * (1 + 25e-6)  # the generator's clock
    t = np.arange(int(0.5 * fs)) / fs

    def current(t):
        return 0.7 * np.sin(2 * np.pi * f * t)

    def force(t):
        return 170.0 + 40.0 * np.sin(2 * np.pi * f * t - 0.05) + 3.0 * np.sin(4 * np.pi * f * t + 1.0)

    rec = Recording(None, fs, {"current_A": current(t), "force_N": force(t)},
                    {"rig": "ecore_pm", "frequency_Hz": nominal, "current_pp_A": 1.4})
    i, x = demo._loop(rec, f, "force_N")
    assert i.size == x.size and i[0] == i[-1] and x[0] == x[-1]  # a closed loop for the figure
    when = np.arange(i.size - 1) / (i.size - 1) / f  # its points, phase 0 at sample 0
    # cubic interpolation at 312.5 samples per period: error ~ (2 pi 2f / fs)^4 / 384 x 3 N, 1e-7 N
    assert np.max(np.abs(x[:-1] - force(when))) < 1e-5 * 40.0
    assert np.max(np.abs(i[:-1] - current(when))) < 1e-5 * 0.7
