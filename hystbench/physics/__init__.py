"""Models shared by the simulator, the estimators and the compensator.  Imports nothing of ours
beyond the shared vocabulary (errors, config)."""

from .hysteresis import HysteresisState, PreisachHysteresis
from .eddy import lamination_eddy_coefficient, slab_permeability_factor
from .instrument import InstrumentModel
from .iron import ComplexPermeabilityIron, RayleighIron
from .mec import ECoreGeometry, ECoreMEC, Magnet
from .permeance import gap_permeance
from .voice_coil import VoiceCoil

__all__ = ["ECoreGeometry", "ECoreMEC", "Magnet", "InstrumentModel", "VoiceCoil", "gap_permeance",
           "lamination_eddy_coefficient", "slab_permeability_factor", "PreisachHysteresis",
           "HysteresisState", "ComplexPermeabilityIron", "RayleighIron"]
