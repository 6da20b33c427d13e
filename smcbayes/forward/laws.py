"""The scalar laws of the built-in effects, written once for every solver path.

Each law is a plain function of floats or of NumPy arrays of one shape (elementwise,
SI units), built only from arithmetic and the NumPy functions numba compiles for scalars
(``np.exp``, ``np.expm1``, ``np.minimum``, ``np.maximum``) and :func:`select`.  The effect
classes call them on ``(P,)`` arrays (the NumPy marching path and the 2-D solver); the
compiled marching kernel compiles the very same functions with numba and calls them on
one row's floats.  So a formula lives here and nowhere else.

The derivations are in :mod:`~smcbayes.forward.material` and the modules of the effects:
:mod:`~smcbayes.forward.effects.compressibility` (Toll & Manson 1995 power law with a
pore-closure factor after Gutowski, Morigaki & Cai 1987),
:mod:`~smcbayes.forward.effects.thermal` (first conduction mode of a slab, Arrhenius
viscosity, Kamal-Sourour kinetics, the cure factor of thesis eq. 3.1) and
:mod:`~smcbayes.forward.effects.press`.
"""

from __future__ import annotations

from typing import TypeVar

import numpy as np
from numpy.typing import NDArray

Array = NDArray[np.float64]
X = TypeVar("X", float, Array)

GAS_CONSTANT = 8.314462618
"""J/(mol K)"""
CURE_E = 60e3
"""activation energy of the cure kinetics (J/mol); the orders are m_c = 1, n_c = 2"""
RK4_STEP = 0.25
"""largest sub-step of the cure integration, in units of 1 / (k1 + k2)"""
MAX_CURE_SUBSTEPS = 50.0
"""most sub-steps of the cure integration in one solver step"""
MAX_CURE_FACTOR = 1e12  # past gelation the charge no longer flows; keep numbers finite


def select(condition: bool | NDArray[np.bool_], a: X | float, b: X | float) -> X:
    """``np.where(condition, a, b)``.

    numba's ``np.where`` returns a 0-d array for floats; the compiled kernel therefore
    registers a scalar implementation of this function (``a if condition else b``).
    """
    return np.where(condition, a, b)


def compaction_pressure(solid: X, solid0: X, modulus: X, exponent: X) -> X:
    """P_c(s) = k_c ((s/s0)^b - 1)(1 - s0)/(1 - s) (Pa), zero below s0.

    Infinite where s0 >= 1 (no pores) or s >= 1 (pores closed).  Arguments: solid
    fraction s (-), initial solid fraction s0 (-), modulus k_c (Pa), exponent b (-).
    """
    grow = np.maximum(solid / solid0, 1.0) ** exponent - 1.0
    out = modulus * grow * (1.0 - solid0) / (1.0 - solid)
    return select((solid0 >= 1.0) | (solid >= 1.0), np.inf, np.maximum(out, 0.0))


def mould_temperature_relaxation(T: X, T_mould: float, gap: X, diffusivity: X, dt: X) -> X:
    """Mean charge temperature (K) after ``dt`` (s) of heating at gap ``gap`` (m).

    Exact over the step for the first conduction mode, tau_h = H^2 / (pi^2 kappa)
    (``diffusivity`` kappa in m^2/s).
    """
    tau_h = gap**2 / (np.pi**2 * diffusivity)
    return T_mould + (T - T_mould) * np.exp(-dt / tau_h)


def arrhenius_factor(T: X, T_mould: float, T_b: X) -> X:
    """Zero-shear viscosity factor exp(T_b (1/T - 1/T_mould)) (-) at charge temperature T (K)."""
    return np.exp(T_b * (1.0 / T - 1.0 / T_mould))


def cure_rate_shift(T: X, T_mould: float) -> X:
    """Arrhenius factor of the cure rate constants at T (K) relative to the mould (-)."""
    return np.exp(-CURE_E / GAS_CONSTANT * (1.0 / T - 1.0 / T_mould))


def cure_substeps(dt: X, k1: X, k2: X) -> X:
    """Runge-Kutta sub-steps over ``dt`` (s): h (k1 + k2) <= RK4_STEP, 1 to 50 (float).

    RK4_STEP = 0.25 keeps the local error near 1e-5 of the degree of cure.  Counted per
    row, so a row's result does not depend on the other rows of its batch.
    """
    return np.maximum(np.minimum(np.ceil(dt * (k1 + k2) / RK4_STEP), MAX_CURE_SUBSTEPS), 1.0)


def cure_rk4_step(alpha: X, k1: X, k2: X, h: X) -> X:
    """One classical Runge-Kutta step of ``h`` (s) of the Kamal-Sourour kinetics
    d alpha/dt = (k1 + k2 alpha)(1 - alpha)^2 (m_c = 1, n_c = 2; k in 1/s), capped at 1."""

    def rate(a: X) -> X:
        a = np.minimum(np.maximum(a, 0.0), 1.0)
        u = 1.0 - a
        return (k1 + k2 * a) * (u * u)

    r1 = rate(alpha)
    r2 = rate(alpha + 0.5 * h * r1)
    r3 = rate(alpha + 0.5 * h * r2)
    r4 = rate(alpha + h * r3)
    return np.minimum(alpha + (h / 6.0) * (r1 + 2.0 * (r2 + r3) + r4), 1.0)


def cure_factor(alpha: X, alpha_g: X, c1: X, c2: X, cap: float) -> X:
    """Cure factor of the viscosity, (alpha_g/(alpha_g - alpha))^(c1 + c2 alpha) (thesis
    eq. 3.1), at most ``cap``; infinite (or ``cap``) at and past gelation."""
    g = alpha_g - alpha
    factor = select(g > 0, (alpha_g / g) ** (c1 + c2 * alpha), np.inf)
    return np.minimum(factor, cap)


def ramp_speed(v_set: X, t: X, ramp_time: X) -> X:
    """Free ram speed (m/s) at time t (s) accelerating to ``v_set`` with time constant
    ``ramp_time`` (s): v_set (1 - exp(-t / t_r))."""
    return v_set * -np.expm1(-t / ramp_time)
