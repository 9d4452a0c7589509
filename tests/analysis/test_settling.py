"""The start-up transient (issue 10): windows that overlap an operating-point change or the bench's
settling after it are never estimated, live or offline, and the settling time is physical."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from hystbench.acquisition.record import record_log
from hystbench.analysis.log_recordings import read_mcap_recording
from hystbench.analysis.method import measure_delays
from hystbench.formats.recording import Recording
from hystbench.analysis.settling import settling_time_s
from hystbench.acquisition.sources import RigSource
from hystbench.acquisition.stages import WindowEstimator
from hystbench.sim_backend.rig import SimulatedRig

F = 480.0  # the top of the paper's range: two periods (the old rule) are shortest here
OFF_S = 0.05  # output off this long, then on: what the daemon and the bench do at start


def test_settling_time_is_ten_of_the_slowest_instrument_time_constants() -> None:
    # the paper's load cell + frame: fn 4450 Hz, zeta 0.012 -> tau = 1 / (zeta 2 pi fn) = 2.98 ms
    frame = 1.0 / (0.012 * 2 * math.pi * 4450.0)
    assert settling_time_s({"rig": "ecore_pm"}) == pytest.approx(10 * frame, rel=1e-9)
    # a frame mode at 850 Hz with zeta 0.02 rings longer; a charge-amplifier high-pass longer still
    mode = 1.0 / (0.02 * 2 * math.pi * 850.0)
    assert settling_time_s(SimulatedRig("ecore", effects={"frame_resonance": True}).metadata()) == \
        pytest.approx(10 * mode, rel=1e-9)
    assert settling_time_s(SimulatedRig("ecore", effects={"charge_amp_highpass": 0.5}).metadata()) == \
        pytest.approx(5.0, rel=1e-9)
    assert settling_time_s({"rig": "no such rig"}) == 0.0


def _switched_on(seconds: float) -> RigSource:
    """ecore_pm at 480 Hz, powered with the output off (as the emulated bench starts), switched on
    after OFF_S by a command between blocks."""
    rig = SimulatedRig("ecore_pm", frequency_hz=F, current_pp_a=1.4, seed=5)
    rig.output_enabled = False
    return RigSource(rig, block_samples=1000, pace="max", duration_s=seconds)


def _stream(src: RigSource) -> list:
    blocks, out = src.blocks(), []
    for k, b in enumerate(blocks):
        out.append(b)
        if (k + 1) * 1000 == round(OFF_S * src.fs_hz):
            src.set_output(True)  # applied at the next block
    return out


def test_the_first_window_after_output_on_agrees_with_the_steady_state() -> None:
    """Live: the first window the estimator accepts after the output came on has the standard
    error and the delays of the steady-state windows (before: the ringing frame inflated its
    standard error 2-5 fold and biased it)."""
    src = _switched_on(0.6)
    est = WindowEstimator(src.fs_hz, src.metadata(), min_hop_s=0.0)
    out = [e.to_json() for b in _stream(src) for e in est.push(b)]
    assert out and not any(e["error"] for e in out)
    on = round(OFF_S * src.fs_hz)
    first, steady = out[0], out[len(out) // 2:]
    assert first["first_index"] >= on + settling_time_s(src.metadata()) * src.fs_hz
    for k in ("hysteresis", "instrument", "total"):
        se = np.mean([e["phases_std_deg"][k] for e in steady])
        mean = np.mean([e["phases_deg"][k] for e in steady])
        assert first["phases_std_deg"][k] < 1.25 * se, k  # no transient left in its residual
        assert abs(first["phases_deg"][k] - mean) < 3 * math.hypot(se, first["phases_std_deg"][k]), k


def test_a_log_read_offline_starts_after_the_settling_too(tmp_path: Path) -> None:
    """Offline (``estimate LOG.mcap``, ``export``): the recording starts where the live estimator
    started, so its first window is as good as the rest."""
    src = _switched_on(0.3)
    blocks = iter(_stream(src))

    class Replayed:  # the stream above, through the pipeline into a log
        name, channels, fs_hz, pace = src.name, src.channels, src.fs_hz, "max"

        def metadata(self):
            return src.metadata()

        def blocks(self, stop=None):
            return blocks

        def close(self):
            pass

    res = record_log(Replayed(), tmp_path / "on.mcap", estimation={"min_hop_s": 0.0}, timeout_s=60)
    rec = read_mcap_recording(tmp_path / "on.mcap")
    start = round(rec.t0_s * rec.fs_hz)
    assert start == res["estimates"][0]["first_index"]
    assert start >= round(OFF_S * src.fs_hz) + settling_time_s(src.metadata()) * src.fs_hz
    win = round(10 * rec.fs_hz / F)

    def window(k: int):
        a = k * win
        return measure_delays(Recording(None, rec.fs_hz, {c: rec.channels[c][a:a + win] for c in
                                                          ("current_A", "flux_Wb", "force_N")}, rec.metadata))

    first, rest = window(0), [window(k) for k in range(3, 8)]
    for k in ("hysteresis", "instrument", "total"):
        se = np.mean([d.phase_std_deg(k) for d in rest])
        assert first.phase_std_deg(k) < 1.25 * se, k
        assert abs(first.phase_deg(k) - np.mean([d.phase_deg(k) for d in rest])) < 3 * math.hypot(
            se, first.phase_std_deg(k)), k
