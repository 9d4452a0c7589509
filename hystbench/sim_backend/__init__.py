"""The simulated rig: truth physics with switchable effects (and, later, the instrument emulators).

A real backend, not a test helper: the daemon, the demo and the tests all run on it when no
hardware is attached.  The effect catalogue it switches is configuration vocabulary and has one
home, :mod:`hystbench.config.effects`.
"""

from .rig import DEFAULT_FS_HZ, SimulatedRig

__all__ = ["SimulatedRig", "DEFAULT_FS_HZ"]
