"""The digitiser source's sustained sample rate through the real VISA path (issue 15).

The emulated SCPI digitiser (``sim_backend/emulators/digitiser.py``) on 127.0.0.1 is given
``--seconds`` of the simulated rig's four signals at 100 kS/s in its memory (computed before the
clock starts, so the rig's own speed is not measured), then the driver's frame source
(``drivers/digitiser.py``: pyvisa with the pure-Python pyvisa-py backend, TCPIP SOCKET) reads it
all, channel by channel, segment by segment (``:WAV:SOUR``, ``:WAV:PRE?``, ``:WAV:DATA?`` with a
definite-length block of int16 codes), and joins the four channels into frames.  The rate is
samples per channel per second of wall time; CPU time of the process (both ends: the emulator
serves from this process) is the second figure.  Rows for several ``points`` per read.

Target: at least 2x the bench's 100 kS/s per channel (four channels) at the default 100 000
points per read, so the source keeps up with room to spare.  Exit status 1 when missed.
Run: ``python -m benchmarks digitiser [--seconds N] [--json]``.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

FS_HZ = 100_000.0
TARGET_FACTOR = 2.0  # sustained rate / fs_hz, per channel, all four channels
POINTS = (100_000, 20_000, 5_000)
SCALES = {"current_A": 0.2, "force_N": 50.0, "flux_Wb": 1e-5, "command_V": 1.0}


def _filled_emulator(seconds: float):
    from hystbench.sim_backend.emulators.digitiser import DigitiserEmulator
    from hystbench.sim_backend.rig import SimulatedRig

    rig = SimulatedRig("ecore_pm", fs_hz=FS_HZ, seed=0, frequency_hz=320.0, current_pp_a=1.4)
    n = int(round(seconds * FS_HZ))
    emu = DigitiserEmulator(FS_HZ, {s: (k, v) for k, (s, v) in enumerate(SCALES.items(), start=1)},
                            memory_points=n + 1)
    emu.running = True
    block = 10_000
    for _ in range(0, n, block):
        emu.on_block(rig.read(block))
    return emu, n


def _read_all(seconds: float, points: int) -> dict:
    from hystbench.drivers.digitiser import DigitiserFrameSource, ScpiDigitiser, VisaLink
    from hystbench.drivers.protocols import scpi_digitiser as sd

    emu, n = _filled_emulator(seconds)
    link = VisaLink(emu.addresses["visa"], 10.0)
    src = DigitiserFrameSource(ScpiDigitiser(link, sd.dialect("generic"), FS_HZ, max_points=points),
                               [f"CHAN{k}" for k in range(1, 5)], poll_s=0.0)
    try:
        src.open()
        emu.running = False  # what is in memory is the whole test: no new samples come
        got, frames = 0, 0
        t0, c0 = time.perf_counter(), time.process_time()
        while got < n:
            for f in src.read_frames(1.0):
                got += f.n
                frames += 1
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    finally:
        src.close()
        emu.close()
    return {"points_per_read": points, "samples_per_channel": got, "frames": frames, "wall_s": wall, "cpu_s": cpu,
            "rate_per_channel_wall": got / wall, "rate_per_channel_cpu": got / cpu,
            "mb_per_s": got * 4 * 2 / wall / 1e6}


def run(seconds: float = 10.0) -> dict:
    rows = [_read_all(seconds, p) for p in POINTS]
    head = rows[0]
    return {"machine": platform.machine(), "python": platform.python_version(), "fs_hz": FS_HZ, "channels": 4,
            "seconds_of_samples": seconds, "rows": rows, "target_factor": TARGET_FACTOR,
            "passed": head["rate_per_channel_wall"] >= TARGET_FACTOR * FS_HZ}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks digitiser", description=__doc__.split("\n")[0])
    parser.add_argument("--seconds", type=float, default=10.0, help="seconds of samples (at 100 kS/s) to read")
    parser.add_argument("--json", action="store_true", help="print the result as JSON")
    args = parser.parse_args(argv)
    result = run(args.seconds)
    if args.json:
        print(json.dumps(result, indent=2))
        return 0 if result["passed"] else 1
    print(f"digitiser source through pyvisa-py (TCPIP SOCKET on 127.0.0.1), 4 channels of int16, "
          f"{args.seconds:g} s of samples at {FS_HZ / 1e3:g} kS/s")
    print(f"{'points/read':>12} {'kS/s/ch (wall)':>15} {'kS/s/ch (CPU)':>14} {'MB/s':>7} {'x real time':>12}")
    for r in result["rows"]:
        print(f"{r['points_per_read']:>12} {r['rate_per_channel_wall'] / 1e3:>15.0f} "
              f"{r['rate_per_channel_cpu'] / 1e3:>14.0f} {r['mb_per_s']:>7.1f} "
              f"{r['rate_per_channel_wall'] / FS_HZ:>12.1f}")
    verdict = "meets" if result["passed"] else "MISSES"
    print(f"{verdict} the target of {TARGET_FACTOR:g}x the bench's {FS_HZ / 1e3:g} kS/s per channel")
    return 0 if result["passed"] else 1


if __name__ == "__main__":
    raise SystemExit(main())
