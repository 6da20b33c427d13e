"""Look-up of effects by name, with the built-in effects registered.

Importing this module imports the modules of the built-in effects, whose classes register
themselves (:func:`~smcbayes.forward.effects.base.register`); effects of users register
the same way.
"""

from __future__ import annotations

from collections.abc import Sequence

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


def check_names(names: Sequence[str], source: str = "effects") -> tuple[str, ...]:
    """``names`` validated: at least one, each registered (else the closest is named), none twice.

    Raises:
        ConfigError: one line naming ``source`` (e.g. ``--effects``) and what is accepted.
    """
    registry = sorted(available())
    chosen = [n.strip() for n in names if n.strip()]
    if not chosen:
        raise ConfigError(f"{source}: no effect named; available: {', '.join(registry)}")
    for name in chosen:
        if name not in registry:
            raise ConfigError(f"{source}: unknown effect '{name}'{closest(name, registry)}; "
                              f"available: {', '.join(registry)}")
    if len(set(chosen)) != len(chosen):
        raise ConfigError(f"{source}: an effect is listed twice")
    return tuple(chosen)
