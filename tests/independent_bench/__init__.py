"""An independent bench simulator, written from the physics, for testing hystbench on a bench it
did not build (issue 27).  It imports nothing from ``hystbench``: only numpy, scipy and the
standard library (tests/independent_bench/test_independence.py and the ``.importlinter`` contract
check this), and every block uses a different model family than ``hystbench.sim_backend``:

- iron: Bouc-Wen hysteresis driven by B, a saturating anhysteretic with its own knee, and the
  lamination's eddy currents as a Cauer ladder (finite-difference half-lamination), solved in
  periodic steady state by harmonic balance; its rate dependence as a power law in dB/dt and a
  Cole-Cole relaxation; its warming over the day as a first-order rise that narrows the Bouc-Wen
  loop alone;
- actuator: a reluctance network with Roters-style fringing; force from the gap fluxes
  (checked against the virtual work of a co-energy map W'(MMF, g));
- magnet: a solid disc's eddy currents as a shorted turn; a temperature coefficient of its MMF;
- instrument: a two-mass load cell + frame, a charge amplifier (high-pass + 2nd-order low-pass),
  an op-amp integrator with finite DC gain and a feedback leak resistor;
- acquisition: sampling clock and generator clock a few ppm off, per-channel skew, 1/f + white
  noise, mains pickup, ADC quantisation.
"""

from .bench import (BASELINE, EFFECT_NAMES, RIGS, BenchConstants, bench_day_plan, effect_params,
                    shuffled_blocks, simulate_recording, write_bench_day)

__all__ = ["BASELINE", "EFFECT_NAMES", "RIGS", "BenchConstants", "bench_day_plan", "effect_params",
           "shuffled_blocks", "simulate_recording", "write_bench_day"]
