"""The press programme and the marching step control, shared by every solver path.

The press closes at the set speed until the force reaches the limit, then holds the force
(force control) for the hold time; an incompressible charge that fills the cavity stops
the gap, and the force reaches the limit within ``jump_time`` on a rigid frame, or as the
ram runs on and loads a compliant one (:func:`load_travel`, :func:`load_time`).
:class:`PressProgramme` holds these numbers; the functions below are its decisions.  They
are plain functions of floats or of NumPy arrays (elementwise), built only from what numba
compiles for scalars, so the 1-D kinematic path, the NumPy marching path, the compiled
marching kernel and the 2-D stepper all call the same code.

The step control of the marching path (:func:`closing_stretch`, :func:`hold_step`) lives
here too: the NumPy and the compiled marching paths share it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol, TypeVar

import numpy as np
from numpy.typing import NDArray

from smcbayes.forward.case import Case
from smcbayes.forward.laws import select

Array = NDArray[np.float64]
X = TypeVar("X", float, Array)

MAX_STRETCH = 4.0
"""largest speed-controlled step, in nominal steps (see :func:`closing_stretch`)"""
STEP_GROWTH = 1.2
"""largest ratio of consecutive speed-controlled steps"""
HOLD_NODE_TOL = 1e-6
"""distance (in schedule nodes) within which a time counts as on a hold-schedule node"""
HOLD_END_TOL = 1e-9
"""time (s) within which the hold counts as over"""
FULL_TOL = 1e-12
"""relative shortfall of the charge area within which the cavity counts as full"""


class MarchOptions(Protocol):
    """The discretisation the marching paths read (see ``Squeeze1DOptions``)."""

    @property
    def closing_steps(self) -> int:
        """Nominal steps over the speed-controlled closing."""

    @property
    def hold_steps(self) -> int:
        """Nodes of the hold schedule."""

    @property
    def jump_time_s(self) -> float:
        """Time (s) for the force to reach the limit once an incompressible charge fills."""

    @property
    def shape_correction(self) -> bool:
        """Whether the square-charge correction of the 1-D force applies."""


@dataclass(frozen=True)
class PressProgramme:
    """Set-speed closing, the switch to force control at the limit and the hold (SI).

    Attributes:
        speed: set closing speed (m/s); a measured ram profile replaces it in
            :meth:`Case.set_speed`.
        force_limit: force at which the press switches to force control (N).
        hold: duration of the force-controlled hold (s).
        jump_time: time for the force to reach the limit once an incompressible charge
            fills the cavity on a rigid frame (s; see :func:`load_time`).
    """

    speed: float
    force_limit: float
    hold: float
    jump_time: float

    @classmethod
    def of(cls, case: Case, jump_time: float) -> PressProgramme:
        """The programme of a configuration."""
        return cls(case.speed, case.force_limit, case.hold, jump_time)

    def reaches_limit(self, force: X) -> X:
        """True where the force has reached the limit (switch to force control)."""
        return reaches_limit(force, self.force_limit)

    def crossing(self, prev_force: X, force: X) -> X:
        """Share of the last step at which the force crossed the limit, in [0, 1]."""
        return crossing_fraction(prev_force, force, self.force_limit)

    def hold_over(self, t: X, t_switch: X) -> X:
        """True where the hold that started at ``t_switch`` (s) is over at ``t`` (s)."""
        return hold_over(t, t_switch, self.hold)


def reaches_limit(force: X, force_limit: float) -> X:
    """True where ``force`` (N) is at or above the limit (N); False for NaN."""
    return force >= force_limit


def crossing_fraction(prev_force: X, force: X, force_limit: float) -> X:
    """Share theta in [0, 1] of the last step at which the force passed the limit.

    Linear in the force between the two ends of the step.  An infinite force is the
    pore-free state of a porous charge, where the step ended: theta = 1 there, and where
    the ends are equal.
    """
    theta = (force_limit - prev_force) / (force - prev_force)
    theta = select(np.isinf(force) | np.isnan(theta), 1.0, theta)
    return np.minimum(np.maximum(theta, 0.0), 1.0)


def step_deflection(delta: X, balanced: X, dt: X, solved_dt: X) -> X:
    """Frame deflection (m) after a speed-controlled step of ``dt`` (s) whose balance was
    solved for a step of ``solved_dt`` (s), from ``delta`` (m) at its start.

    The balance (backward Euler, V + F / (k dt) = U + delta / dt) gives the deflection
    ``balanced`` = F / k = delta + (U - V) dt after a whole step.  A step cut short at the
    cavity fill or the pore-free state takes the same rates over ``dt`` only, so the
    deflection grows by the share ``dt / solved_dt`` of that increment, as the 2-D
    stepper's does.  Taken whole, a cut step loaded the frame by a whole step's worth
    however short it was: a fill just after a step's end found the frame a step further
    loaded than a fill at its end, and the switch time jumped by up to 70 ms as a
    parameter moved the fill across a step's end (``benchmarks/forward_smoothness.py``).
    """
    cut = dt < solved_dt
    share = select(cut, dt / np.maximum(solved_dt, 1e-300), 1.0)
    return select(cut, delta + share * (balanced - delta), balanced)


def frame_load(force: X, delta: X, inv_k: X) -> X:
    """The force (N) a compliant frame carries at a fill of the cavity, that of its
    deflection ``delta`` (m), ``delta / inv_k``; ``force`` (N) on a rigid frame.

    The force the marching evaluates at the filled state balances the step it would take
    next (backward Euler): it lies a step ahead of the frame, by an amount that depends on
    where the fill falls within its step.  The frame's loading started from it, and the
    switch time with it, moved by up to a few ms each time a parameter moved the fill
    across a step's end.  The deflection is the state the fill leaves
    (:func:`step_deflection`).
    """
    return select(inv_k > 0.0, delta / np.maximum(inv_k, 1e-300), force)


def hold_over(t: X, t_switch: X, hold: float) -> X:
    """True where the hold begun at ``t_switch`` (s) is over at ``t`` (s)."""
    return t >= t_switch + hold - HOLD_END_TOL


def fills_and_stops(incompressible: X, area: X, area_mould: float, force_control: X) -> X:
    """True where an incompressible charge has just filled the cavity under speed
    control: the press stops and the force goes to the limit."""
    return incompressible & (area >= area_mould * (1.0 - FULL_TOL)) & np.logical_not(force_control)


def load_travel(force: X, force_limit: float, inv_k: X, beta: X) -> X:
    """Free travel of the ram (m) that loads a compliant frame from ``force`` (N) to the
    limit (N) once an incompressible charge has filled the cavity.

    The gap stops, but the ram runs on at free (1 - beta F / F_limit) (``beta`` its load
    slowdown) and loads the frame of compliance ``inv_k`` (m/N): dF = k (1 - beta F /
    F_limit) dX over the ram's free travel X, so

        X = F_limit / (beta k) ln((1 - beta F / F_limit) / (1 - beta)),

    inv_k (F_limit - F) at beta = 0; 0 on a rigid frame.  A force above the limit counts as
    the limit.
    """
    force = np.minimum(force, force_limit)
    b = select(beta > 1e-9, beta, 0.5)  # a placeholder where the linear form applies
    curved = inv_k * force_limit / b * np.log((1.0 - b * force / force_limit) / (1.0 - b))
    return select(beta > 1e-9, curved, inv_k * (force_limit - force))


def load_time(force: X, force_limit: float, inv_k: X, free: X, beta: X, jump_time: float) -> X:
    """Time (s) from the fill of the cavity by an incompressible charge, at ``force`` (N), to
    the force limit (N): :func:`load_travel` at the ram's free speed ``free`` at the fill
    (m/s, held), at least ``jump_time`` (on a rigid frame: the press's own reaction).

    The force rises linearly in time at beta = 0; with the load slowdown it approaches the
    limit exponentially, F_limit / beta (1 - (1 - beta F / F_limit) exp(-beta k free t /
    F_limit)), which the solvers' nodes at the fill and at the limit only span (their
    output interpolates linearly between them).
    """
    return np.maximum(load_travel(force, force_limit, inv_k, beta) / free, jump_time)


def hold_step(t: X, t_switch: X, speed: X, dt0: X, hold: float, hold_steps: float,
              travel_step: X) -> X:
    """Force-controlled step (s): the next node of a geometric schedule over the hold.

    Nodes lie at t_switch + dt0 r^(k / hold_steps), r = hold / dt0, so the steps grow from
    the nominal closing step ``dt0`` (s) to cover the hold in ``hold_steps`` nodes; a row
    sitting on a node (to rounding) steps to the next one.  The step is capped so that the
    gap closes by at most ``travel_step`` (m) at the closing ``speed`` (m/s).
    """
    ratio = np.maximum(hold / dt0, 1.0 + 1e-9)
    elapsed = np.maximum(t - t_switch, 0.0)
    node = hold_steps * np.log(np.maximum(elapsed, dt0 * 1e-3) / dt0) / np.log(ratio)
    node = select(np.isnan(node), -1.0, node)
    k = np.minimum(np.maximum(np.floor(node + HOLD_NODE_TOL) + 1.0, 0.0), hold_steps)
    target = t_switch + dt0 * ratio ** (k / hold_steps)
    dt = np.minimum(target, t_switch + hold) - t
    cap = select(speed > 0, travel_step / speed, np.inf)
    return np.maximum(np.minimum(dt, cap), 1e-12)


def closing_stretch(ram: X, force_rate: X, ram_rate: X, travel: X, t_close: X, v_ref: float,
                    force_limit: float) -> X:
    """Factor in [1, MAX_STRETCH] on the nominal speed-controlled step.

    The change per step of the ram position (share of its travel to the limit, gap travel
    + F_limit / k, in units of the nominal travel), of the ram speed (share of the set
    speed) and of the force (share of the limit) stays at or below what the nominal step
    allows.  ``ram`` is the ram speed (m/s), the rates are absolute values over the last
    step (inf or NaN: none yet), ``t_close`` the nominal closing time (s).
    """
    rate = np.maximum(np.maximum(ram / travel, ram_rate * t_close) / v_ref,
                      force_rate * t_close / force_limit)
    inv = 1.0 / rate
    inv = select(np.isnan(inv), 1.0, select(inv == np.inf, MAX_STRETCH, inv))
    return np.minimum(np.maximum(inv, 1.0), MAX_STRETCH)
