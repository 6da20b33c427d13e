"""The press itself: frame compliance and a finite ram acceleration / slowing under load.

**press_compliance**: the frame deflects by F / k_press, so the measured ram displacement
is the gap change plus F / k_press, and while the force rises the gap closes slower than
the ram.  The solver integrates the deflection by backward Euler (stable for a stiff frame).

**speed_ramp**: the ram accelerates to the set speed with a time constant t_r and slows
under load, U = U_set (1 - exp(-t / t_r)) (1 - beta F / F_limit).
"""

from __future__ import annotations

import numpy as np

from smcbayes.forward import laws
from smcbayes.forward.case import Case
from smcbayes.forward.effects.base import Array, Effect, Params, register
from smcbayes.forward.parameters import Parameter


@register
class PressCompliance(Effect):
    """Elastic press frame between the measured ram position and the true gap."""

    name = "press_compliance"
    description = "frame deflection F/k: ram displacement = gap change + F/k_press"
    parameters = (
        Parameter("k_press_kN_mm", "k_press", "kN/mm", 1e6, 50.0, 5000.0, True, 500.0,
                  (0.0, np.inf), "press frame stiffness"),
    )
    kernel_slots = ()  # the kernel takes the compliance of the whole stack

    def compliance(self, case: Case, p: Params, rows: int) -> Array:
        return np.broadcast_to(1.0 / p["k_press"], (rows,)).astype(float)


@register
class SpeedRamp(Effect):
    """Finite ram acceleration and slowing under load."""

    name = "speed_ramp"
    description = "ram accelerates to the set speed (time constant) and slows under load"
    parameters = (
        Parameter("ramp_time_s", "ramp_time", "s", 1.0, 0.01, 5.0, True, 0.5, (0.0, np.inf),
                  "time constant of the ram's acceleration to the set speed"),
        Parameter("load_slowdown", "load_slowdown", "-", 1.0, 0.0, 0.9, False, 0.2, (-1e-300, 1.0),
                  "fraction of the set speed lost at the force limit"),
    )
    kernel_slots = ("ramp_time", "load_slowdown")

    def ram_speed(self, case: Case, p: Params, t: Array, v_set: Array) -> tuple[Array, Array]:
        free = laws.ramp_speed(v_set, t, p["ramp_time"])
        return free, np.broadcast_to(p["load_slowdown"], t.shape).astype(float)
