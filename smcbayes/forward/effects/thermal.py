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

from smcbayes.forward.case import Case
from smcbayes.forward.effects.base import Array, Effect, Params, State, register
from smcbayes.forward.material import cure_factor
from smcbayes.forward.parameters import Parameter
from smcbayes.units import ZERO_C_K

GAS_CONSTANT = 8.314462618
"""J/(mol K)"""
CURE_E = 60e3
"""activation energy of the cure kinetics (J/mol); the orders are m_c = 1, n_c = 2"""
RK4_STEP = 0.25
"""largest sub-step of the cure integration, in units of 1 / (k1 + k2)"""
MAX_CURE_FACTOR = 1e12  # past gelation the charge no longer flows; keep numbers finite


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

    def initial_state(self, case: Case, p: Params, rows: int) -> State:
        return {"temperature": np.broadcast_to(p["T_start_C"] + ZERO_C_K, (rows,)).astype(float)}

    def advance(self, case: Case, p: Params, state: State, gap: Array, dt: Array) -> State:
        tau_h = gap**2 / (np.pi**2 * p["diffusivity"])
        T = state["temperature"]
        return {"temperature": case.T_mould + (T - case.T_mould) * np.exp(-dt / tau_h)}

    def viscosity_factors(self, case: Case, p: Params, state: State) -> tuple[Array, Array]:
        T = state["temperature"]
        return np.exp(p["T_b"] * (1.0 / T - 1.0 / case.T_mould)), np.ones_like(T)


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

    def initial_state(self, case: Case, p: Params, rows: int) -> State:
        return {"cure": np.zeros(rows)}

    def advance(self, case: Case, p: Params, state: State, gap: Array, dt: Array) -> State:
        T = charge_temperature(case, state)
        shift = 1.0 if T is None else np.exp(-CURE_E / GAS_CONSTANT * (1.0 / T - 1.0 / case.T_mould))
        k1, k2 = p["k1"] * shift, p["k2"] * shift
        alpha = state["cure"]
        # classical Runge-Kutta sub-steps with h (k1 + k2) <= 0.25 (local error ~1e-5 of
        # the degree of cure); counted per row, so a row's result does not depend on the
        # other rows of its batch
        n_sub = np.minimum(np.ceil(dt * (k1 + k2) / RK4_STEP), 50.0)
        n_sub = np.maximum(n_sub, 1.0)
        h = dt / n_sub
        for i in range(int(np.max(n_sub, initial=1.0))):
            r1 = _cure_rate(alpha, k1, k2)
            r2 = _cure_rate(alpha + 0.5 * h * r1, k1, k2)
            r3 = _cure_rate(alpha + 0.5 * h * r2, k1, k2)
            r4 = _cure_rate(alpha + h * r3, k1, k2)
            step = np.minimum(alpha + (h / 6.0) * (r1 + 2.0 * (r2 + r3) + r4), 1.0)
            alpha = step if i == 0 else np.where(i < n_sub, step, alpha)
        return {"cure": alpha}

    def viscosity_factors(self, case: Case, p: Params, state: State) -> tuple[Array, Array]:
        factor = cure_factor(state["cure"], p["alpha_g"], p["c1"], p["c2"])
        return np.ones_like(factor), np.minimum(factor, MAX_CURE_FACTOR)


def _cure_rate(alpha: Array, k1: Array, k2: Array) -> Array:
    """Kamal-Sourour rate d alpha / dt (1/s) for m_c = 1, n_c = 2; all ``(P,)``."""
    a = np.minimum(np.maximum(alpha, 0.0), 1.0)
    u = 1.0 - a
    return (k1 + k2 * a) * (u * u)
