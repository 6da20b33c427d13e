"""Reference solutions the solvers are verified against (tests and ``benchmarks/``).

:func:`newtonian_bar_on_frame`: planar squeeze flow of a Newtonian full-width bar on a
compliant press frame under speed control, up to the fill of the cavity.  The squeeze force
of a bar of half-length a and width W at gap H closing at V is F = 8 mu V W a^3 / H^3
(lubrication theory, p = 6 mu V (a^2 - x^2) / H^3), and a H = vol / (2 W) holds the
volume; the frame holds F = k (H - X) with X = H0 - U t the ram's gap, so

    dH/dt = -k (H - X) H^6 / C,   C = 8 mu W (vol / (2 W))^3,

solved by an implicit Runge-Kutta method (Radau IIA) at tight tolerance.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray
from scipy.integrate import solve_ivp

from smcbayes.forward.case import Case

__all__ = ["newtonian_bar_on_frame"]

Array = NDArray[np.float64]


def newtonian_bar_on_frame(case: Case, k: float, mu: float) -> tuple[float, Callable[[Array], Array]]:
    """Fill time (s) and the force (kN) at given times (s) of the full-width bar ``case``
    (planar, closing at ``case.speed``) of viscosity ``mu`` (Pa s) on a frame of stiffness
    ``k`` (N/m), up to the fill."""
    W, h0, U, vol = case.width, case.gap0, case.speed, case.area0 * case.gap0
    C = 8.0 * mu * W * (vol / (2.0 * W)) ** 3
    h_full = vol / case.area_mould

    def filled(t: float, y: Array) -> float:
        return float(y[0] - h_full)

    filled.terminal = True  # type: ignore[attr-defined]
    sol = solve_ivp(lambda t, y: [-k * (y[0] - (h0 - U * t)) * y[0] ** 6 / C], (0.0, 1e3 * h0 / U), [h0],
                    method="Radau", rtol=1e-11, atol=1e-14, events=filled, dense_output=True)

    def force_kN(t: Array) -> Array:
        return k * (sol.sol(t)[0] - (h0 - U * t)) / 1e3

    return float(sol.t_events[0][0]), force_kN
