"""When ``Bench.acquire`` runs out of time it says why and what to do (issue 16): a stalled stream,
an emulated bench slower than real time (a busy machine), a timeout shorter than the samples asked
for, or streams whose indices never meet.  The old message said only "within the timeout"."""

from hystbench.drivers.bench import timeout_reason

FS = 100_000.0
NAMES = ("signal_generator", "current_amplifier", "charge_amplifier", "flux_integrator")


def counts(*values):
    return dict(zip(NAMES, values))


def test_an_emulated_bench_slower_than_real_time_is_named_with_its_rate_and_the_fix():
    msg = timeout_reason(0, 10_000, 5.0, counts(150_000, 160_000, 150_000, 140_000), FS, emulated=True)
    assert msg.startswith("bench: only 0 of 10000 aligned samples within 5.0 s: ")
    assert "the emulated bench produced 140000 samples in 5.0 s, 28% of real time at 100 kS/s" in msg
    assert "too slow (CPU-bound)" in msg and "free CPU" in msg and "longer timeout" in msg


def test_hardware_slower_than_fs_points_at_the_sample_rate():
    msg = timeout_reason(10, 10_000, 2.0, counts(200_000, 200_000, 20_000, 200_000), FS, emulated=False)
    assert "charge_amplifier delivered 20000 samples in 2.0 s, 10% of [bench] fs_hz = 100000" in msg


def test_a_silent_stream_is_named():
    msg = timeout_reason(0, 10_000, 5.0, counts(500_000, 500_000, 500_000, 0), FS, emulated=True)
    assert "flux_integrator delivered no samples meanwhile (its stream is stalled" in msg


def test_nothing_at_all_from_an_emulated_bench_says_the_machine_is_too_busy():
    msg = timeout_reason(0, 10_000, 5.0, counts(0, 0, 0, 0), FS, emulated=True)
    assert "the emulated bench produced no samples at all" in msg and "free CPU" in msg


def test_a_timeout_shorter_than_the_duration_at_real_time():
    msg = timeout_reason(30_000, 100_000, 0.3, counts(30_000, 30_000, 30_000, 30_000), FS, emulated=True)
    assert "1 s of samples take 1 s to come: allow a longer timeout" in msg


def test_streams_at_full_rate_whose_indices_never_meet():
    msg = timeout_reason(0, 10_000, 1.0, counts(100_000, 100_000, 100_000, 100_000), FS, emulated=False,
                         ends=dict(zip(NAMES, (100_000, 100_000, 100_000, 9_000_000))))
    assert "their sample indices do not meet" in msg and "'flux_integrator': 9000000" in msg
