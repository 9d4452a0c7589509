"""Shared fixtures: the force models of each E-core rig, fitted once per run on the identification
sweep (``FIT_GRID``: 40, 160, 480 Hz x 0.3-1.5 A-pp, seed 1000) and read back from their model file
as a user has them, and a helper that simulates a recording the fit did not see (other seeds, other
frequencies and amplitudes)."""

import pytest

from hystbench.compensator import ModelSet
from hystbench.compensator.sweeps import period_data
from hystbench.sim_backend.recordings import simulated_sweep


@pytest.fixture(scope="session")
def models_pm(model_file_of):
    return ModelSet.load(model_file_of("ecore_pm"))  # as a user has them after `model fit`: from the file


@pytest.fixture(scope="session")
def models_ecore(model_file_of):
    return ModelSet.load(model_file_of("ecore"))


@pytest.fixture(scope="session")
def unseen():
    """The helper below, as a fixture (test modules here are not a package)."""
    return _unseen


def _unseen(rig: str, f: float, ipp: float, seed: int = 5000):
    """One recording the models were not fitted on, as period averages (0.5 s or 80 periods)."""
    rec = simulated_sweep(rig, [f], [ipp], seed=seed, duration_s=max(0.5, 80.0 / f))[0]
    return period_data(rec)
