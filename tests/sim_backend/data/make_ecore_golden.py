"""Writes ecore_golden.npz: the simulated E-core rig's samples as the numpy implementation gave them
on commit 3b1f019 (before the E-core numba kernel, issue 14).  It is a fixed reference for "the same
samples as today", independent of either implementation; do not regenerate it to make a test pass.

    .venv/bin/python tests/sim_backend/data/make_ecore_golden.py
"""

from pathlib import Path

import numpy as np

from hystbench.sim_backend.rig import SimulatedRig

QUIET = {"sensor_noise": False, "adc_quantisation": False}
#: (key, rig, seed, effects, frequency_hz, samples, block_size)
RUNS = [
    ("pm_adc", "ecore_pm", 1, None, None, 4000, 1000),  # the preset's effects: noise and ADC on
    ("pm_quiet", "ecore_pm", 1, QUIET, None, 3000, 1000),
    ("ecore_quiet", "ecore", 2, QUIET, 480.0, 2000, 700),
]


def main() -> None:
    out: dict[str, np.ndarray] = {}
    for key, rig, seed, effects, f, n, block in RUNS:
        r = SimulatedRig(rig, seed=seed, effects=effects, frequency_hz=f)
        rec = r.record(n / r.fs_hz, block_size=block)
        q = r.effects.get("adc_quantisation")
        for ch, x in rec.channels.items():
            if q is None:
                out[f"{key}/{ch}"] = x
            else:
                from hystbench.sim_backend.measurement import _NOISE_KEYS
                lsb = 2.0 * float(q[_NOISE_KEYS[ch]]) / 2 ** int(q["bits"])
                codes = np.round(x / lsb)
                assert np.array_equal(codes * lsb, x)
                out[f"{key}/{ch}"] = codes.astype(np.int16)
                out[f"{key}/{ch}/lsb"] = np.array(lsb)
    np.savez_compressed(Path(__file__).with_name("ecore_golden.npz"), **out)


if __name__ == "__main__":
    main()
