"""Look-up of effects by name, with the built-in effects registered.

Importing this module imports the modules of the built-in effects, whose classes register
themselves (:func:`~smcbayes.forward.effects.base.register`); effects of users register
the same way.
"""

from __future__ import annotations

from smcbayes.errors import ConfigError, closest
from smcbayes.forward.effects.base import Effect, registered
from smcbayes.forward.effects.compressibility import Compressibility
from smcbayes.forward.effects.press import PressCompliance, SpeedRamp
from smcbayes.forward.effects.thermal import Curing, Heating

BUILT_IN: tuple[type[Effect], ...] = (Compressibility, PressCompliance, SpeedRamp, Heating, Curing)
"""The built-in effects (registered on import of their modules)."""


def available() -> dict[str, type[Effect]]:
    """Registered effects by name (built-ins and any registered since)."""
    return registered()


def get_effect(name: str) -> Effect:
    """Instantiate a registered effect; unknown names raise with the closest match."""
    registry = available()
    if name not in registry:
        raise ConfigError(f"unknown effect '{name}'{closest(name, list(registry))}; "
                          f"available: {', '.join(sorted(registry))}")
    return registry[name]()
