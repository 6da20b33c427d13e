"""The effect contract: switchable physics plugged into the forward solvers.

An effect has a name, a description, parameters (units, bounds, default prior) and
implements any of the hooks below; the defaults are neutral (the base model).  The solver
only talks to an :class:`EffectStack`, which combines the hooks of the enabled effects.
All arrays have shape ``(P,)`` (one value per parameter set) and are SI.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import ClassVar

import numpy as np
from numpy.typing import NDArray

from smcbayes.errors import ConfigError
from smcbayes.forward.case import Case
from smcbayes.forward.parameters import Parameter

Array = NDArray[np.float64]
State = dict[str, Array]
Params = Mapping[str, Array]


class Effect:
    """Base class of all effects; every hook defaults to 'no effect'."""

    name: ClassVar[str] = ""
    description: ClassVar[str] = ""
    parameters: ClassVar[tuple[Parameter, ...]] = ()

    kernel_slots: ClassVar[tuple[str, ...] | None] = None
    """Symbols of the per-row parameters (SI) this effect hands to the compiled marching
    kernel (:mod:`smcbayes.forward.kernel_layout`); None: the kernel does not implement
    the effect, which then runs on the NumPy marching path."""
    kernel_state: ClassVar[tuple[str, ...]] = ()
    """Names of the state variables of :meth:`initial_state` the compiled kernel carries."""

    def kernel_values(self, case: Case, p: Params, rows: int) -> dict[str, Array]:
        """Values of :attr:`kernel_slots`, each ``(rows,)`` SI: the parameters themselves."""
        return {name: np.broadcast_to(p[name], (rows,)).astype(float) for name in self.kernel_slots or ()}

    def initial_state(self, case: Case, p: Params, rows: int) -> State:
        """Extra state variables of this effect at first contact."""
        return {}

    def advance(self, case: Case, p: Params, state: State, gap: Array, dt: Array) -> State:
        """State after a step of ``dt`` (s) at gap ``gap`` (m); must accept ``dt = 0``."""
        return {}

    def viscosity_factors(self, case: Case, p: Params, state: State) -> tuple[Array, Array] | None:
        """Factors on the zero-shear viscosity and the cure factor, or None."""
        return None

    def solid_fraction0(self, case: Case, p: Params, rows: int) -> Array | None:
        """Initial solid (consolidated) volume fraction of the charge, or None (= 1)."""
        return None

    def compaction(self, case: Case, p: Params, solid: Array) -> tuple[Array, Array] | None:
        """Compaction pressure P_c(s) (Pa) and bulk viscosity (Pa s), or None."""
        return None

    def compliance(self, case: Case, p: Params, rows: int) -> Array | None:
        """Press frame compliance 1/k (m/N), or None."""
        return None

    def ram_speed(self, case: Case, p: Params, t: Array, v_set: Array) -> tuple[Array, Array] | None:
        """Free ram speed (m/s) at time ``t`` and its load sensitivity beta (-), or None.

        The ram speed under load F is ``free * (1 - beta * F / F_limit)``.
        """
        return None


_REGISTRY: dict[str, type[Effect]] = {}


def register(cls: type[Effect]) -> type[Effect]:
    """Class decorator adding an effect to the registry under ``cls.name``."""
    _REGISTRY[cls.name] = cls
    return cls


def registered() -> dict[str, type[Effect]]:
    """Effects registered so far, by name (the built-ins register when
    :mod:`smcbayes.forward.effects` is imported; see :mod:`~smcbayes.forward.effects.registry`)."""
    return dict(_REGISTRY)


class EffectStack:
    """The enabled effects, combined into the quantities the solver asks for."""

    def __init__(self, effects: Sequence[Effect] = ()) -> None:
        names = [e.name for e in effects]
        if len(set(names)) != len(names):
            raise ConfigError(f"an effect is enabled twice: {names}")
        self.effects = tuple(effects)

    @property
    def names(self) -> list[str]:
        """Names of the enabled effects."""
        return [e.name for e in self.effects]

    @property
    def parameters(self) -> tuple[Parameter, ...]:
        """Parameters of all enabled effects."""
        return tuple(p for e in self.effects for p in e.parameters)

    def initial_state(self, case: Case, p: Params, rows: int) -> State:
        state: State = {}
        for e in self.effects:
            state.update(e.initial_state(case, p, rows))
        return state

    def advance(self, case: Case, p: Params, state: State, gap: Array, dt: Array) -> State:
        new = dict(state)
        for e in self.effects:
            new.update(e.advance(case, p, state, gap, dt))
        return new

    def viscosity_factors(self, case: Case, p: Params, state: State, rows: int) -> tuple[Array, Array]:
        eta_f, cure = np.ones(rows), np.ones(rows)
        for e in self.effects:
            out = e.viscosity_factors(case, p, state)
            if out is not None:
                eta_f, cure = eta_f * out[0], cure * out[1]
        return eta_f, cure

    def solid_fraction0(self, case: Case, p: Params, rows: int) -> Array | None:
        for e in self.effects:
            s0 = e.solid_fraction0(case, p, rows)
            if s0 is not None:
                return s0
        return None

    def compaction(self, case: Case, p: Params, solid: Array) -> tuple[Array, Array]:
        for e in self.effects:
            out = e.compaction(case, p, solid)
            if out is not None:
                return out
        return np.full(solid.shape, np.inf), np.zeros(solid.shape)

    def compliance(self, case: Case, p: Params, rows: int) -> Array:
        total = np.zeros(rows)
        for e in self.effects:
            c = e.compliance(case, p, rows)
            if c is not None:
                total = total + c
        return total

    def ram_speed(self, case: Case, p: Params, t: Array, v_set: Array) -> tuple[Array, Array]:
        free, beta = v_set, np.zeros_like(v_set)
        for e in self.effects:
            out = e.ram_speed(case, p, t, free)
            if out is not None:
                free, beta = out[0], beta + out[1]
        return free, beta
