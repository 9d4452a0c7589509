"""Compile hystbench's numba kernels once, in one process, before `make test` starts its workers.

numba compiles a kernel on its first call and caches it beside its module; on a fresh clone every
worker (and every daemon or command line a test starts) compiled the same kernels side by side until
one had written the cache: a fresh clone's first `make test` took 254 s against 215 s for the next.
This runs each kernel family once on a small input, with the argument types the suite uses; what it
misses is compiled by the first test that needs it, as before.  With the cache warm it takes about
2 s.  It asserts nothing: the kernels' tests compare them with their numpy references.
"""

from __future__ import annotations

import numpy as np

from hystbench.jit import enabled


def main() -> None:
    if not enabled():
        return
    from hystbench.analysis.method import measure_delays
    from hystbench.config import load_material
    from hystbench.drivers.protocols.framing import cobs_decode, cobs_encode
    from hystbench.physics.hysteresis import PreisachHysteresis
    from hystbench.physics.hysteresis_kernel import field_along
    from hystbench.sim_backend.recordings import simulated_sweep

    recs = {rig: simulated_sweep(rig, (80.0,), (0.6,), seed=1)  # the rig's, the iron's and the instruments'
            for rig in ("ecore_pm", "ecore", "voicecoil_ferrite")}
    rec = recs["ecore_pm"][0]
    measure_delays(rec)  # the sine fits' least squares and their robust screen
    force = rec.channels["force_N"]
    force[force.size // 2] += 10.0 * np.ptp(force)  # a glitch: the screen's medians
    measure_delays(rec)
    iron = PreisachHysteresis.from_config(load_material("M330-50A"))
    field_along(iron, 0.5 * np.sin(np.linspace(0.0, 6.3, 200)), iron.initial_state())
    cobs_decode(cobs_encode(bytes(range(256)) * 4))


if __name__ == "__main__":
    main()
