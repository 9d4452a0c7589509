"""hystbench: measure and cancel the magnetic hysteresis in the force of reluctance actuators.

Packages, in the order their imports may point (see docs/architecture.md):
``errors`` and ``blocks`` (shared vocabulary) <- ``drivers``, ``physics`` <- ``sim_backend`` <-
``acquisition``, ``compensator``, ``reports``, ``cli``.  Nothing imports ``cli``.
"""

__version__ = "0.1.0"
__all__ = ["__version__"]
