"""Material laws of the thesis (eq. 3.1-3.3), vectorised over parameter sets.

All functions are SI: stresses in Pa, viscosities in Pa s, shear rates in 1/s, slip
velocities in m/s, temperatures in K.  Every argument broadcasts, so a column of
parameters ``(P, 1)`` against a row of stresses ``(1, M)`` gives ``(P, M)``.

Modified Cross law (eq. 3.1, with the Arrhenius law eq. 3.2 written relative to the
mould temperature so that ``B`` is the zero-shear viscosity at ``T_mould``; this keeps the
thesis's bounds B in [1e3, 1e5] Pa s meaningful when the heating effect moves ``T``):

    eta = eta0 / (1 + (eta0 * gdot / tau_star)**(1 - n)) * cure_factor
    eta0 = B * exp(T_b * (1/T - 1/T_mould))
    cure_factor = (alpha_g / (alpha_g - alpha))**(c1 + c2 * alpha)

With n = 1 the Cross law gives eta0/2, not eta0; the Newtonian limit is tau_star -> inf.

Moldflow slip law (eq. 3.3): v_s = a_s / (1 + (tau_c / tau_w)**k) * tau_w**m with the
threshold exponent k = 10 and the coefficient a_s (m/s/Pa^m, default 1e-8).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from smcbayes.forward import laws

Array = NDArray[np.float64]


def zero_shear_viscosity(B: ArrayLike, T_b: ArrayLike, T: ArrayLike,
                         T_mould: ArrayLike) -> Array:
    """Arrhenius zero-shear viscosity eta0 (Pa s) at temperature ``T`` (K)."""
    return np.asarray(B) * laws.arrhenius_factor(np.asarray(T), np.asarray(T_mould), np.asarray(T_b))


def cure_factor(alpha: ArrayLike, alpha_g: ArrayLike, c1: ArrayLike, c2: ArrayLike) -> Array:
    """Viscosity factor of the degree of cure, (alpha_g/(alpha_g-alpha))^(c1+c2 alpha).

    Infinite at and past gelation (alpha >= alpha_g).
    """
    alpha = np.asarray(alpha, dtype=float)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        return np.asarray(laws.cure_factor(alpha, np.asarray(alpha_g), np.asarray(c1),
                                           np.asarray(c2), np.inf))


def cross_viscosity(gdot: ArrayLike, eta0: ArrayLike, tau_star: ArrayLike, n: ArrayLike) -> Array:
    """Modified Cross viscosity (Pa s) at shear rate ``gdot`` (1/s), cure factor 1."""
    eta0 = np.asarray(eta0, dtype=float)
    return eta0 / (1.0 + (eta0 * np.asarray(gdot) / np.asarray(tau_star)) ** (1.0 - np.asarray(n)))


def cross_stress(gdot: ArrayLike, eta0: ArrayLike, tau_star: ArrayLike, n: ArrayLike) -> Array:
    """Shear stress tau = eta(gdot) * gdot (Pa)."""
    return cross_viscosity(gdot, eta0, tau_star, n) * np.asarray(gdot)


def cross_shear_rate(tau: ArrayLike, eta0: ArrayLike, tau_star: ArrayLike, n: ArrayLike,
                     iterations: int = 30) -> Array:
    """Invert the Cross law: the shear rate (1/s) at which the stress is ``tau`` (Pa).

    In reduced variables y = tau/tau_star, u = eta0 gdot / tau_star the law reads
    y = u / (1 + u^(1-n)); g(ln u) = ln u - ln(1 + u^(1-n)) - ln y has slope in [n, 1],
    so Newton's method on ln u converges from ln u0 = max(ln y, ln y / n).
    """
    tau = np.asarray(tau, dtype=float)
    tau_star = np.asarray(tau_star, dtype=float)
    n = np.asarray(n, dtype=float)
    ln_y = np.log(tau / tau_star)
    ln_u = np.maximum(ln_y, ln_y / n)
    one_minus_n = 1.0 - n
    for _ in range(iterations):
        w = np.exp(np.clip(one_minus_n * ln_u, -700.0, 700.0))
        frac = w / (1.0 + w)
        g = ln_u - np.log1p(w) - ln_y
        step = g / (1.0 - one_minus_n * frac)
        ln_u = ln_u - step
        if np.all(np.abs(step) < 1e-13):
            break
    return np.exp(ln_u) * tau_star / np.asarray(eta0, dtype=float)


def slip_velocity(tau_w: ArrayLike, a_s: ArrayLike, tau_c: ArrayLike, m: ArrayLike,
                  threshold_exponent: float = 10.0) -> Array:
    """Moldflow slip velocity (m/s) at wall shear stress ``tau_w`` (Pa)."""
    tau_w = np.asarray(tau_w, dtype=float)
    with np.errstate(divide="ignore", over="ignore"):
        ratio = np.asarray(tau_c, dtype=float) / tau_w
        damp = 1.0 / (1.0 + ratio**threshold_exponent)
    return np.asarray(a_s) * damp * tau_w ** np.asarray(m)
