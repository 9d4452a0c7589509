"""compensator: force models, their inverses and the learning correction (issue 6).

    PeriodData            one operating point as period averages (``sweeps.period_data`` from a recording)
    StaticLaw             F = k0 + k1 j + k2 j^2 (Eq. 1) and its inverse, reachable range
    NonHysteretic         Eq. 1 with the static law identified from the sweep
    PaperModel            Eq. 6: Eq. 1 with the current delayed by theta_hyst(f)
    HysteresisEddyModel, DescribingFunctionModel, RayleighLoopModel
                          ours: the iron's share of the current described the way the sweep chooses
                          (Preisach + eddy, complex gain per harmonic, Rayleigh loops), then the law
    ModelSet, fit_models  all three from one sweep (``calibration``: law and magnet bias;
                          ``identify``: the choice by held-out error); JSON file of ``hystbench model fit``
    predict_measured      a model's force as the load cell reports it (instrument applied)
    ForceReference        a periodic force to track: sine with offset, multi-sine, any table
    LearningController    iterative learning on the instrument-corrected force error, with its guard
    Actuation, RigActuation, BenchActuation   what drives the actuator (a SimulatedRig; the drivers)
    run_closed_loop       feed-forward plus learning on an Actuation, per-iteration report
    CompensatorStage      the online stage: follows the live theta_hyst estimate (pipeline hook API)

Imports: analysis (the method's delays, the one period averager), physics, formats, config and the
shared vocabulary, never the live chain (docs/architecture.md).  ``compensator.sweeps`` (recordings
to period averages, ``quick_models``: the identification on the simulated rig) is imported on its own.
"""

from .actuation import Actuation, BenchActuation, RigActuation
from .data import PeriodData
from .errors import CompensatorError, LearningStopped, UnreachableReference
from .describing import DescribingFunctionModel
from .hysteresis_eddy import HysteresisEddyModel, IronScaling
from .learning import IterationReport, LearningConfig, LearningController
from .loop import LoopResult, run_closed_loop
from .models import (FORMAT, MODEL_KINDS, ForceModel, ModelSet, NonHysteretic, PaperModel, fit_models, force_error,
                     predict_measured)
from .rayleigh_loop import RayleighLoopModel
from .reference import ForceReference
from .stage import CompensatorStage
from .static import StaticLaw

__all__ = ["PeriodData", "StaticLaw", "ForceModel", "NonHysteretic", "PaperModel", "HysteresisEddyModel",
           "DescribingFunctionModel", "RayleighLoopModel",
           "IronScaling", "ModelSet", "fit_models", "predict_measured", "force_error", "FORMAT", "MODEL_KINDS",
           "ForceReference", "LearningConfig", "LearningController", "IterationReport", "Actuation",
           "RigActuation",
    "BenchActuation", "run_closed_loop", "LoopResult", "CompensatorStage", "CompensatorError",
           "UnreachableReference", "LearningStopped"]
