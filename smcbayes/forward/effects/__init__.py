"""Switchable physics for the sim-to-real gap diagnosis (design 4.3).

Importing this package registers the built-in effects: ``compressibility``, ``heating``,
``curing``, ``press_compliance`` and ``speed_ramp``.
"""

from smcbayes.forward.effects.base import Effect, EffectStack, register
from smcbayes.forward.effects.registry import available, check_names, get_effect

__all__ = ["Effect", "EffectStack", "available", "check_names", "get_effect", "register"]
