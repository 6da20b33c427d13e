"""What one parameter set brings to the 2-D solver (:mod:`smcbayes.forward.stepper2d`):
its flux law and the effects that act on the whole charge and on the ram.

The flux law is the 1-D solver's tabulated one (:mod:`smcbayes.forward.flux`) of one row.
``heating`` and ``curing`` act as in the 1-D solver, on one charge-mean temperature and
degree of cure whose factors scale every cell's viscosity; ``speed_ramp`` gives the ram's
free speed and its slowing under load, ``press_compliance`` the frame's compliance.  All go
through the effects' own hooks (:mod:`smcbayes.forward.effects`), so a formula lives in one
place.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from smcbayes.forward.case import Case
from smcbayes.forward.effects.base import EffectStack
from smcbayes.forward.flux import MaterialTable
from smcbayes.forward.grid2d import Fluidity

__all__ = ["ChargeEffects", "Law"]

Array = NDArray[np.float64]


@dataclass
class Law:
    """Flux law of one parameter set: q(tau) = H slip + H^2 coeff (m^2/s), ``(M,)``.

    ``coeff`` is the shear part at the row's own zero-shear viscosity; ``table`` (the
    row's one-row :class:`~smcbayes.forward.flux.MaterialTable`) and ``eta0`` (Pa s) give it
    again under the viscosity and cure factors of the effects (:meth:`at`).  Shapes: the
    stress grid ``tau`` (Pa), ``slip`` (m/s) and ``coeff`` (m^2/s per m^2 of gap), each
    ``(M,)``.
    """

    tau: Array
    slip: Array
    coeff: Array
    table: MaterialTable
    eta0: float

    def at(self, gap: float, eta_f: float = 1.0, cure: float = 1.0) -> Fluidity:
        """The law at ``gap`` (m) with the viscosity factor ``eta_f`` and cure factor ``cure``."""
        coeff = self.coeff
        if eta_f != 1.0 or cure != 1.0:
            shear = self.table.shear_at(np.array([cure]))[0]
            coeff = shear / (2.0 * self.eta0 * eta_f * self.tau**2)
        return Fluidity(self.tau, gap * self.slip + gap * gap * coeff, gap)


@dataclass
class ChargeEffects:
    """The effects of one parameter set on the whole charge and the press, through the
    effects' own hooks (the 1-D solver's): ``heating`` and ``curing`` (their state at first
    contact, its advance over a step and the factors on the zero-shear viscosity and the
    cure factor; one charge-mean state, so the cells share the charge's mean temperature
    and degree of cure), ``speed_ramp`` (the ram's speed, :meth:`ram_speed`) and
    ``press_compliance`` (the frame's compliance, :meth:`compliance`).

    Attributes:
        case: the configuration in SI.
        p: the row's SI parameters by symbol, each ``(1,)``.
        effects: the enabled effects.
    """

    case: Case
    p: dict[str, Array]
    effects: EffectStack

    def initial(self) -> dict[str, Array]:
        """The effects' state at first contact, each ``(1,)`` (empty without heating or curing)."""
        return self.effects.initial_state(self.case, self.p, 1)

    def advance(self, extra: dict[str, Array], gap: float, dt: float) -> dict[str, Array]:
        """The state after ``dt`` (s) at the step's start gap ``gap`` (m)."""
        if not extra:
            return extra
        return self.effects.advance(self.case, self.p, extra, np.array([gap]), np.array([dt]))

    def factors(self, extra: dict[str, Array]) -> tuple[float, float]:
        """(viscosity factor, cure factor) of the state ``extra``."""
        if not extra:
            return 1.0, 1.0
        eta_f, cure = self.effects.viscosity_factors(self.case, self.p, extra, 1)
        return float(eta_f[0]), float(cure[0])

    def ram_speed(self, t: float) -> tuple[float, float]:
        """The ram's free speed (m/s) at ``t`` (s) and its load slowdown beta (-): under a
        force F it closes at free (1 - beta F / F_limit) (``speed_ramp``, on the set speed
        or the measured ram profile's)."""
        at = np.array([t])
        free, beta = self.effects.ram_speed(self.case, self.p, at, self.case.set_speed(at))
        return float(free[0]), float(beta[0])

    def compliance(self) -> float:
        """The press frame's compliance 1/k (m/N; 0 without ``press_compliance``)."""
        return float(self.effects.compliance(self.case, self.p, 1)[0])
