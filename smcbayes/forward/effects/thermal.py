"""Heating of a cold charge and curing of the resin: effects on the viscosity.

**heating**: the charge enters at T_start below the mould temperature and heats through
its thickness; its mean temperature relaxes to the mould's with the time constant of the
first conduction mode of a slab of thickness H,

    dT/dt = (T_mould - T) / tau_h,   tau_h = H^2 / (pi^2 kappa),

integrated exactly over each step (tau_h at the step's gap).  The zero-shear viscosity
follows Arrhenius relative to the mould temperature, eta0 = B exp(T_b (1/T - 1/T_mould)),
so B keeps its meaning (viscosity at the mould temperature).

**curing**: Kamal-Sourour kinetics with rate constants given at the mould temperature and
an Arrhenius temperature dependence (activation energy E),

    d alpha/dt = (k1 + k2 alpha^m_c) (1 - alpha)^n_c,  k_i(T) = k_i(T_mould) exp(-E/R (1/T - 1/T_mould)),

and the viscosity factor of thesis eq. 3.1, (alpha_g / (alpha_g - alpha))^(c1 + c2 alpha).
m_c = 1, n_c = 2 and E = 60 kJ/mol are fixed constants of the effect.
"""

from __future__ import annotations

import numpy as np

from smcbayes.forward import laws
from smcbayes.forward.case import Case
from smcbayes.forward.effects.base import Array, Effect, Params, State, register
from smcbayes.forward.laws import CURE_E, GAS_CONSTANT, MAX_CURE_FACTOR, RK4_STEP
from smcbayes.forward.parameters import Parameter
from smcbayes.units import ZERO_C_K

__all__ = ["CURE_E", "GAS_CONSTANT", "MAX_CURE_FACTOR", "RK4_STEP", "Curing", "Heating",
           "charge_temperature"]


def charge_temperature(case: Case, state: State) -> Array | None:
    """Mean charge temperature (K) if the heating effect tracks it, else None."""
    return state.get("temperature")


@register
class Heating(Effect):
    """Cold charge heating up in the hot mould; Arrhenius viscosity."""

    name = "heating"
    description = "charge colder than the mould, through-thickness heating, Arrhenius viscosity"
    parameters = (
        Parameter("T_start_C", "T_start_C", "C", 1.0, 15.0, 135.0, False, 25.0, (-273.15, 1000.0),
                  "charge temperature at first contact"),
        Parameter("diffusivity_mm2_s", "diffusivity", "mm2/s", 1e-6, 0.05, 2.0, True, 0.3,
                  (0.0, np.inf), "through-thickness thermal diffusivity kappa"),
        Parameter("T_b_K", "T_b", "K", 1.0, 1000.0, 15000.0, False, 5000.0, (0.0, 1e6),
                  "Arrhenius activation temperature of the zero-shear viscosity"),
    )
    kernel_slots = ("diffusivity", "T_b")
    kernel_state = ("temperature",)

    def initial_state(self, case: Case, p: Params, rows: int) -> State:
        return {"temperature": np.broadcast_to(p["T_start_C"] + ZERO_C_K, (rows,)).astype(float)}

    def advance(self, case: Case, p: Params, state: State, gap: Array, dt: Array) -> State:
        T = laws.mould_temperature_relaxation(state["temperature"], case.T_mould, gap, p["diffusivity"], dt)
        return {"temperature": T}

    def viscosity_factors(self, case: Case, p: Params, state: State) -> tuple[Array, Array]:
        T = state["temperature"]
        return laws.arrhenius_factor(T, case.T_mould, p["T_b"]), np.ones_like(T)


@register
class Curing(Effect):
    """Resin cure during flow (Kamal-Sourour) raising the viscosity (thesis eq. 3.1)."""

    name = "curing"
    description = "Kamal-Sourour cure kinetics and the cure factor of the viscosity"
    parameters = (
        Parameter("k1_1_s", "k1", "1/s", 1.0, 1e-5, 1e-1, True, 1e-3, (0.0, np.inf),
                  "Kamal-Sourour rate constant k1 at the mould temperature"),
        Parameter("k2_1_s", "k2", "1/s", 1.0, 1e-4, 1.0, True, 2e-2, (-1e-300, np.inf),
                  "autocatalytic rate constant k2 at the mould temperature"),
        Parameter("c1", "c1", "-", 1.0, 0.0, 10.0, False, 3.0, (-1e-300, 100.0),
                  "cure-factor exponent c1"),
        Parameter("c2", "c2", "-", 1.0, 0.0, 20.0, False, 5.0, (-1e-300, 100.0),
                  "cure-factor exponent c2"),
        Parameter("alpha_g", "alpha_g", "-", 1.0, 0.2, 0.9, False, 0.5, (0.0, 1.0),
                  "degree of cure at gelation"),
    )
    kernel_slots = ("k1", "k2", "c1", "c2", "alpha_g")
    kernel_state = ("cure",)

    def initial_state(self, case: Case, p: Params, rows: int) -> State:
        return {"cure": np.zeros(rows)}

    def advance(self, case: Case, p: Params, state: State, gap: Array, dt: Array) -> State:
        T = charge_temperature(case, state)
        shift = 1.0 if T is None else laws.cure_rate_shift(T, case.T_mould)
        k1, k2 = p["k1"] * shift, p["k2"] * shift
        alpha = state["cure"]
        n_sub = laws.cure_substeps(dt, k1, k2)
        h = dt / n_sub
        # rows needing fewer sub-steps keep their value once done
        for i in range(int(np.max(n_sub, initial=1.0))):
            step = laws.cure_rk4_step(alpha, k1, k2, h)
            alpha = step if i == 0 else np.where(i < n_sub, step, alpha)
        return {"cure": alpha}

    def viscosity_factors(self, case: Case, p: Params, state: State) -> tuple[Array, Array]:
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            factor = laws.cure_factor(state["cure"], p["alpha_g"], p["c1"], p["c2"], MAX_CURE_FACTOR)
        return np.ones_like(factor), factor
