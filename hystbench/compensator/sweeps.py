"""From recordings to the compensator's inputs, and back to what a recording would show.

The models are fitted on period averages (:class:`~.data.PeriodData`), one per recording of a
sweep: the method's delays give the true frequency and theta_hyst, the one synchronous average
(:mod:`hystbench.analysis.periodic`) the waveforms.  :func:`quick_models` does the whole
identification on the simulated rig (what ``hystbench compensate`` runs when no model file is
given, and what the tests and benchmarks fit on); :func:`predict_recording` puts a model's force
through the instrument, sample by sample, for ``hystbench model predict``.
"""

from __future__ import annotations

import math
from typing import Callable, Iterable, Mapping

import numpy as np

from ..analysis.estimation import estimation_errors, sine_fit
from ..analysis.method import check_channels, check_fit_quality, measure_delays, recording_name
from ..analysis.periodic import estimate_frequency, synchronous_average
from ..analysis.sense_coil import with_flux
from ..config import load_rig
from ..errors import RecordingError
from ..formats.recording import Recording
from ..physics.instrument import InstrumentModel
from .data import PeriodData
from .errors import CompensatorError
from .models import ModelSet, fit_models, predict_measured
from .periodic import resample

__all__ = ["FIT_GRID", "JUDGE_FREQS_HZ", "period_data", "sweep_data", "quick_models", "quick_instrument",
           "predict_recording"]

#: The identification sweep :func:`quick_models` runs on the simulated rig: three frequencies x
#: four amplitudes (the models are judged elsewhere on what this does not hold).
FIT_GRID = ((40.0, 160.0, 480.0), (0.3, 0.7, 1.1, 1.5))
#: The frequencies the compensator benchmark judges the models at.
JUDGE_FREQS_HZ = (40.0, 80.0, 160.0, 320.0, 480.0)


def period_data(rec: Recording, n_points: int = 1000) -> PeriodData:
    """One recording as the compensator's :class:`~.data.PeriodData` (a sense coil's voltage integrated)."""
    rec = with_flux(rec)
    d = measure_delays(rec)
    avg = synchronous_average(rec, d.frequency_hz, n_points, ("current_A", "flux_Wb", "force_N"))
    se = 2 * np.pi * d.frequency_hz * d.delays_std_s["hysteresis"]
    return PeriodData(recording_name(rec), d.frequency_hz, rec.frequency_hz, rec.current_pp_a,
                      avg.channels["current_A"], avg.channels["flux_Wb"], avg.channels["force_N"],
                      d.theta_hyst_rad, se, avg.noise_rms["force_N"], avg.periods, avg.noise_rms["current_A"])


def sweep_data(recs: Iterable[Recording], tick: Callable[[], None] | None = None) -> tuple[str, list[PeriodData]]:
    """(rig, period averages) of a sweep of one rig; ``tick()`` after each recording (progress)."""
    recs = list(recs)
    rigs = sorted({r.rig for r in recs})
    if len(rigs) != 1:
        raise RecordingError(f"a sweep is one rig; these recordings are of {', '.join(rigs) or 'none'}")
    points = []
    for r in recs:
        points.append(period_data(r))
        if tick is not None:
            tick()
    return rigs[0], points


#: The voice coil's stepped sine that identifies the instrument (paper Sec. IV): 16 points, 10 Hz-45 kHz.
VOICE_COIL_FREQS_HZ = tuple(float(f) for f in np.round(np.geomspace(10.0, 45000.0, 16), 2))


def quick_models(rig: str | Mapping[str, object], *, seed: int = 1000, effects: Mapping[str, object] | None = None,
                 bench: Mapping[str, object] | None = None, instrument: InstrumentModel | None = None,
                 tick: Callable[[], None] | None = None) -> ModelSet:
    """A model set identified from :data:`FIT_GRID` recordings of a simulated bench (about 10 s);
    ``tick()`` twice per recording (simulated, averaged).  ``bench`` is the bench simulated when it
    is not ``rig`` itself (a foreign bench: ``sim_backend.benches``), ``rig`` the preset the fit
    starts from; ``instrument`` the force instrument (default: the preset's)."""
    from ..sim_backend.recordings import simulated_sweep  # the simulator only when asked for

    recs = simulated_sweep(rig if bench is None else bench, *FIT_GRID, seed=seed, effects=effects, tick=tick)
    _, points = sweep_data(recs, tick=tick)
    return fit_models(points, load_rig(rig), instrument)


def quick_instrument(bench: Mapping[str, object], *, seed: int = 77) -> InstrumentModel:
    """The force instrument of a simulated E-core bench as the paper identifies it (Sec. IV): the
    ferrite voice coil (no eddy currents) on the bench's load cell and charge amplifier, a stepped
    sine of :data:`VOICE_COIL_FREQS_HZ`, the two-filter model fitted to force / current."""
    from ..analysis.identification import fit_instrument, frequency_response
    from ..sim_backend.benches import voice_coil_on_load_cell
    from ..sim_backend.recordings import simulate_voice_coil_sweep

    recs = simulate_voice_coil_sweep(voice_coil_on_load_cell(bench), VOICE_COIL_FREQS_HZ, seed=seed,
                                     samples_per_period=100.0)
    return fit_instrument(frequency_response(recs)).model


def predict_recording(models: ModelSet, rec: Recording, kind: str) -> tuple[np.ndarray, np.ndarray]:
    """(time_s, force_N): what the load cell would report for ``rec``'s measured current, sample by
    sample.  The record is taken as steady-state periodic: its current is averaged over whole
    periods at the true frequency, the model's force for that period is put through the
    instrument, and every sample gets the value at its phase."""
    where = recording_name(rec)
    if rec.rig != models.rig:
        raise RecordingError(f"{where}: a {rec.rig!r} recording, but the models are of {models.rig!r}")
    check_channels(rec, ("current_A",))
    with estimation_errors(where):
        f = estimate_frequency(rec.channels["current_A"], rec.fs_hz, rec.frequency_hz, harmonics=3)
        # the current at the sidecar's frequency, as the method checks it: a sidecar that says 100 Hz over
        # a 320 Hz current was predicted at 100 Hz without a word (33 N rms off)
        check_fit_quality(rec, f, {"current_A": (sine_fit(rec.channels["current_A"], rec.fs_hz, f, fit_freq=False), 1)})
    n = 1000
    avg = synchronous_average(rec, f, n, ("current_A",))
    noise = avg.noise_rms["current_A"] / math.sqrt(avg.periods) if avg.periods > 1 else math.nan
    with np.errstate(over="ignore", invalid="ignore"):  # said below, in one line
        pred = predict_measured(models[kind], avg.channels["current_A"], f, models.instrument, current_noise_a=noise)
    if not np.all(np.isfinite(pred)):  # a model file of values beyond any force (1e308 passes as a number)
        raise CompensatorError(f"{where}: the {kind} model predicts a force that is not finite; its file's "
                               "parameters are beyond any bench (fit it again with `hystbench model fit`)")
    fine = resample(pred, 8 * n)  # then linear interpolation at each sample's phase
    phase = np.mod(np.arange(rec.n) / rec.fs_hz * f, 1.0) * fine.size  # the average's phase 0: sample 0
    return rec.time_s(), np.interp(phase, np.arange(fine.size + 1), np.append(fine, fine[0]))
