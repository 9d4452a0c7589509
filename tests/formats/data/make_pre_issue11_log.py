"""How ``pre_issue11.mcap`` was made: a log written by the code as it was before issue 11 typed the
messages (commit d078bcb: estimates spelled ``frequency_Hz``, two raw-block codecs), which
``tests/formats/test_raw_block.py`` reads and replays with today's code.

    mkdir /tmp/old && git archive d078bcb hystbench | tar -x -C /tmp/old
    PYTHONPATH=/tmp/old .venv/bin/python tests/formats/data/make_pre_issue11_log.py \
        tests/formats/data/pre_issue11.mcap 10000 250 0.6
"""
import sys
from pathlib import Path

import hystbench
from hystbench.acquisition.sources import RigSource
from hystbench.cli.pipeline import record_log
from hystbench.sim_backend.rig import SimulatedRig

print(hystbench.__file__, file=sys.stderr)


class Stepped(RigSource):
    """160 Hz, then 320 Hz, then the output off: three operating points in one log."""

    def blocks(self, stop=None):
        for k, b in enumerate(super().blocks(stop)):
            if k == 8:
                self.set_excitation(frequency_hz=320.0)
            if k == 16:
                self.set_output(False)
            yield b


rig = SimulatedRig("ecore_pm", fs_hz=float(sys.argv[2]), frequency_hz=160.0, current_pp_a=1.4, seed=7)
src = Stepped(rig, block_samples=int(sys.argv[3]), pace="max", duration_s=float(sys.argv[4]))
res = record_log(src, Path(sys.argv[1]), estimation={"periods": 4.0, "min_hop_s": 0.0, "settle_periods": 1.0},
                 timeout_s=60)
print(len(res["estimates"]), res["bytes"], file=sys.stderr)
