"""The effect catalogue as the simulator's modules have imported it so far.

The catalogue and its checks live in :mod:`hystbench.config.effects` (a rig preset's
``[effects]`` tables are checked when the preset is loaded, below the simulator); new code
imports from there.
"""

from __future__ import annotations

from ..config.effects import CATALOGUE, Effect, parse_effect_args, resolve_effects, validate_effects

__all__ = ["Effect", "CATALOGUE", "resolve_effects", "parse_effect_args", "validate_effects"]
