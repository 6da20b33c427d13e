"""Closing speeds of the 2-D solver's press controls (:mod:`smcbayes.forward.stepper2d`),
found by root finding on the speed over speed-controlled pressure solves.

* :func:`loaded_speed`: speed control by a ram that slows under load (``speed_ramp``) or a
  frame that deflects (``press_compliance``), balanced over the step;
* :func:`speed_for_force`: force control by the closing speed, the fallback of the bordered
  Newton solve, which can stall when many compacting cells switch on and off together.

Both take ``solve(V)``, the pressure solution (:class:`~smcbayes.forward.grid2d.PressureSolution`)
at closing speed V (m/s) of the state at hand; the force it gives rises with V.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from smcbayes.errors import SolverError
from smcbayes.forward.grid2d import PressureSolution

Solve = Callable[[float], PressureSolution]


@dataclass(frozen=True)
class Balance:
    """The ram's and the frame's side of a speed-controlled step: the gap closes at

        V = free (1 - beta F / F_limit) - (F / k - delta) / dt,

    the ram's free speed ``free`` (m/s) slowed by the force with ``beta`` (-), less the
    growth of the frame's deflection over the step ``dt`` (s) from ``delta`` (m) to F / k
    (backward Euler; ``inv_k`` = 1/k in m/N, 0 for a rigid frame), as in the 1-D solver.
    """

    free: float
    beta: float
    force_limit: float
    inv_k: float
    delta: float
    dt: float

    def excess(self, speed: float, force: float) -> float:
        """e(V) = V - free (1 - beta F / F_limit) + (F / k - delta) / dt (m/s)."""
        return (speed - self.free * (1.0 - self.beta * force / self.force_limit)
                + (self.inv_k * force - self.delta) / self.dt)

    def scale(self, force: float) -> float:
        """Size of the balance's terms (m/s), for its tolerance."""
        return self.free + (self.inv_k * force + self.delta) / self.dt


def loaded_speed(solve: Solve, balance: Balance, start: float, floor: float, name: str) -> PressureSolution:
    """The solution whose speed V makes the :class:`Balance` hold, by Illinois regula falsi.

    The excess e(V) rises with V at a slope of at least 1 (F rises with V), so V - e(V)
    lies on the far side of the root from V: from ``start`` (m/s; the last step's speed:
    with a compliant frame far below the ram's), solves at V - e(V), each held within a
    factor 8 of the last (a stiff frame puts V - e(V) at a vanishing speed, where the
    pressure iteration of a compacting charge can stall), bracket it.  The pressure solve
    holds F to about 1e-6, so the root is taken to that precision of the balance's terms
    (and the bracket's better end once it has shrunk to round-off).  Where even ``floor``
    (m/s) overloads, the ram rests: the solution at the floor.  ``name`` names the
    configuration in errors.
    """

    def excess(V: float) -> tuple[float, float, PressureSolution]:
        sol = solve(V)
        return V, balance.excess(V, sol.force), sol

    near = excess(start)
    tol = 1e-6 * balance.scale(near[2].force)
    for _ in range(60):  # bracket the root, moving by at most 8x a solve
        if abs(near[1]) <= tol:
            return near[2]
        far = excess(min(max(near[0] - near[1], near[0] / 8.0, floor), 8.0 * near[0]))
        if far[1] * near[1] <= 0.0:
            break
        if far[0] <= floor:  # the load holds even a ram at rest
            return far[2]
        near = far
    else:
        raise SolverError(f"configuration '{name}': no closing speed balances the ram and the frame")
    if abs(far[1]) <= tol:
        return far[2]
    lo, hi = (far, near) if near[1] > 0.0 else (near, far)
    side = 0
    for _ in range(60):
        if hi[0] - lo[0] <= 1e-9 * balance.free:
            return min(lo, hi, key=lambda end: abs(end[1]))[2]
        new = excess(hi[0] - hi[1] * (hi[0] - lo[0]) / (hi[1] - lo[1]))
        if abs(new[1]) <= tol:
            return new[2]
        if new[1] < 0:
            lo, hi, side = new, (hi if side != -1 else (hi[0], hi[1] / 2, hi[2])), -1
        else:
            hi, lo, side = new, (lo if side != 1 else (lo[0], lo[1] / 2, lo[2])), 1
    raise SolverError(f"configuration '{name}': the balance of the ram's load slowdown and the "
                      "frame's deflection did not converge")


def speed_for_force(solve: Solve, start: float, floor: float, force_limit: float,
                    name: str) -> PressureSolution | None:
    """The solution at the closing speed whose force is ``force_limit`` (N), by Illinois
    regula falsi in log V from ``start`` (m/s); None when even ``floor`` (m/s) needs more
    than the limit (the press rests).  ``name`` names the configuration in errors."""
    V = start
    sol = solve(V)
    lo: tuple[float, float] | None = None
    hi: tuple[float, float] | None = None
    for _ in range(60):
        if sol.force < force_limit:
            lo = (np.log(V), sol.force - force_limit)
        else:
            hi = (np.log(V), sol.force - force_limit)
        if lo is not None and hi is not None:
            break
        V = 2.0 * V if hi is None else 0.5 * V
        if V < floor:
            return None
        sol = solve(V)
    if lo is None or hi is None:
        raise SolverError(f"configuration '{name}': no closing speed gives the force limit")
    side = 0
    for _ in range(60):  # Illinois regula falsi in log V
        x = hi[0] - hi[1] * (hi[0] - lo[0]) / (hi[1] - lo[1])
        sol = solve(float(np.exp(x)))
        g = sol.force - force_limit
        if abs(g) <= 1e-6 * force_limit:
            return sol
        if g < 0:
            lo, hi, side = (x, g), (hi if side != -1 else (hi[0], hi[1] / 2)), -1
        else:
            hi, lo, side = (x, g), (lo if side != 1 else (lo[0], lo[1] / 2)), 1
    raise SolverError(f"configuration '{name}': force control did not converge")
