"""Time stepping of the 2-D solver through the press protocol (one parameter set).

Speed control at the ram's speed (the set speed or a measured ram profile's; with
``speed_ramp`` ramped up and slowed by the force) until the force limit (located inside a
step by regula falsi in the step size), then force control (the closing speed that gives
F = F_limit, solved together with the pressure) for the hold time.  With
``press_compliance`` the frame deflects by delta = F / k, so under speed control the gap
closes at the ram's speed less the deflection's rate, balanced at the end of the step
(backward Euler, as in the 1-D solver: V + F / (k dt) = U + delta / dt).  An incompressible
charge that fills the cavity stops the gap, and the force jumps to the limit (on a
compliant frame it rises as the ram runs on and loads the frame,
:func:`~smcbayes.forward.programme.load_time`); a porous charge keeps closing by compaction
alone (:mod:`smcbayes.forward.compaction2d`) until the limit and then creeps under it.

Each step solves the pressure of the current state, then moves explicitly: filled cells
lose V dt of content (the gap closes under them), front cells gain the inflow, the solid
moves with the face fluxes, and content above the gap spills on to the nearest open
cells.  With compaction (semi-implicit law) or a compliant frame (the deflection's
balance) the pressure solve depends on the step, so a step that the Courant, fill or
compaction limits cut by more than 30 % is solved again.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from smcbayes.errors import SolverError
from smcbayes.forward.case import AT_REST, Case
from smcbayes.forward.compaction2d import (
    CellCompaction,
    CompactionSink,
    largest_outflow,
    solid_fraction,
    solid_inflow,
)
from smcbayes.forward.grid2d import FULL, Fluidity, Grid, PressureSolution, solve_pressure
from smcbayes.forward.law2d import ChargeEffects, Law
from smcbayes.forward.programme import PressProgramme, load_time, load_travel
from smcbayes.forward.result import STATUS_OK
from smcbayes.forward.speeds2d import Balance, loaded_speed, speed_for_force
from smcbayes.forward.spill2d import spill_with

Array = NDArray[np.float64]
RETRY = 0.7
"""A step cut below this share of the step its pressure was solved for is solved again."""
POROUS = 1e-8
"""Pore share of the full cavity below which the charge counts as pore-free."""
LAG = 0.1
"""Largest implicit (lag) part of a compacting cell's pressure, as a share of it (or of 1 %
of the limit's mean pressure, whichever is larger), at 100 closing steps."""
PORE_STEP = 0.25
"""Largest share of a cell's remaining pore fraction closed in one step, at 100 closing
steps.  Both compaction limits scale with 100 / closing_steps, so that the step count
alone refines every step of a run."""
MAX_NODES = 100_000
"""A run that needs more steps than this stops with :class:`SolverError` (never hangs)."""
SNAP = 1e-4
"""Open capacity (in cells) below which a porous charge counts as filling the cavity."""


@dataclass(frozen=True)
class HeleShaw2DOptions:
    """Discretisation of the 2-D solver.

    Attributes:
        cells: cells along the longer mould side (whole mould; rounded up to even).
        courant: largest share of a cell's capacity a front cell may gain per step.
        closing_steps: minimum steps over the speed-controlled closing.
        hold_steps: minimum steps over the force-controlled closing.
        per_decade, tau_min_Pa, tau_max_Pa: stress grid of the flux table.
        output_closing_points, output_hold_points: samples per output curve.
        jump_time_s: time for the force to reach the limit once the cavity is full, on a
            rigid frame.
        snapshots: number of fill-fraction fields kept per run (evenly spaced in time over
            the closing, plus the switch instant).
        use_symmetry: solve a half or quarter mould where the layout allows.
    """

    cells: int = 48
    courant: float = 0.5
    closing_steps: int = 100
    hold_steps: int = 40
    per_decade: int = 12
    tau_min_Pa: float = 1e-2
    tau_max_Pa: float = 1e9
    output_closing_points: int = 200
    output_hold_points: int = 50
    jump_time_s: float = 0.05
    snapshots: int = 5
    use_symmetry: bool = True


@dataclass
class State:
    """State of one run: time (s), gap (m), charge thickness per cell (m) and solid
    volume per unit area (m), both ``(nx, ny)``, the effects' state of the whole
    charge (the mean temperature of ``heating``, the degree of cure of ``curing``; each
    ``(1,)``) and the frame's deflection (m; 0 without ``press_compliance``)."""

    t: float
    gap: float
    h: Array
    sigma: Array
    extra: dict[str, Array] = field(default_factory=dict)
    delta: float = 0.0


@dataclass
class Run:
    """Node record of one parameter set (SI), with fill and solid-fraction snapshots."""

    t: list[float] = field(default_factory=list)
    gap: list[float] = field(default_factory=list)
    area: list[float] = field(default_factory=list)
    force: list[float] = field(default_factory=list)
    deflection: list[float] = field(default_factory=list)
    volume: list[float] = field(default_factory=list)
    solid: list[float] = field(default_factory=list)
    solid_volume: list[float] = field(default_factory=list)
    snap_t: list[float] = field(default_factory=list)
    snap_f: list[Array] = field(default_factory=list)
    snap_s: list[Array] = field(default_factory=list)
    switch: float = 0.0
    status: str = STATUS_OK


@dataclass
class Rates:
    """Force (N) and gap closing speed V (m/s) at a state, with the flow solution there
    (None when nothing moves: an incompressible charge fills the cavity, or a porous one
    rests under the force), and under speed control the ram's speed under the step's load
    (m/s; None under force control, where the frame's deflection holds at F_limit / k)."""

    force: float
    speed: float
    sol: PressureSolution | None
    sink: CompactionSink | None = None
    ram: float | None = None


class Stepper:
    """Time stepping of one parameter set; ``compaction`` None for an incompressible charge,
    ``charge`` None without effects on the whole charge or the press (``heating``,
    ``curing``, ``speed_ramp``, ``press_compliance``)."""

    def __init__(self, case: Case, grid: Grid, law: Law, options: HeleShaw2DOptions,
                 compaction: CellCompaction | None, charge: ChargeEffects | None = None) -> None:
        self.case, self.grid, self.law, self.o, self.comp = case, grid, law, options, compaction
        self.charge = charge
        self.inv_k = 0.0 if charge is None else charge.compliance()
        """The frame's compliance 1/k (m/N)."""
        self.press = PressProgramme.of(case, options.jump_time_s)
        self.run = Run()
        self.guess: Array | None = None
        self.speed_guess: float | None = None
        self.snap_area = list(np.linspace(case.area0, case.area_mould, options.snapshots))
        self.gap_end = case.gap_full * (1.0 if compaction is None else compaction.solid0)
        # a measured profile sets the pace by its mean speed over the closing, as in 1-D
        v_ref = case.speed if case.profile is None else case.profile.pace(case.gap0 - self.gap_end)
        self.dt_max = (case.gap0 - self.gap_end) / (v_ref * options.closing_steps)
        self.refine = 100.0 / options.closing_steps
        self.dt = self.dt_max
        """Step (s) the next pressure solve is taken over (the semi-implicit compaction and
        the frame's deflection balance over it)."""

    def initial(self, h0: Array) -> State:
        """State at first contact from the charge thickness per cell (m)."""
        s0 = 1.0 if self.comp is None else self.comp.solid0
        extra = {} if self.charge is None else self.charge.initial()
        return State(0.0, self.case.gap0, h0, s0 * h0, extra)

    def fluidity(self, st: State) -> Fluidity:
        """The flux law at ``st``'s gap, under its viscosity and cure factors."""
        factors = (1.0, 1.0) if self.charge is None else self.charge.factors(st.extra)
        return self.law.at(st.gap, *factors)

    def solid(self, st: State) -> Array:
        """Solid fraction per cell, ``(nx, ny)`` (s0 in empty cells)."""
        if self.comp is None:
            return np.ones_like(st.h)
        return solid_fraction(st.h, st.sigma, self.comp.solid0)

    def measure(self, st: State) -> tuple[float, float, float, float]:
        """Filled area (m^2), bulk volume (m^3), mean solid fraction and solid volume (m^3)."""
        g = self.grid
        w = g.multiplicity * g.cell_area
        area = w * float(np.minimum(st.h / st.gap, 1.0).sum())
        bulk, solid = w * float(st.h.sum()), w * float(st.sigma.sum())
        return area, bulk, solid / bulk, solid

    def rates(self, st: State, force_control: bool) -> Rates | None:
        """Force and closing speed at ``st``; None once an incompressible charge (or one
        whose pores are all closed) fills the cavity."""
        c, F_lim = self.case, self.case.force_limit
        full = st.h >= st.gap * FULL
        sink = None
        if self.comp is not None:
            if full.all():  # all the closing goes into the pores: keep the step's compaction small
                s = self.solid(st)
                if float(np.sum((1.0 - s) * st.h)) <= POROUS * float(st.h.sum()):
                    return None  # pores closed to round-off: as incompressible
                V = self.ram_speed(st.t)[0] if not force_control else (self.speed_guess or c.speed)
                self.dt = min(self.dt, PORE_STEP * self.refine * float(np.min((1.0 - s) / s)) * st.gap / V)
            sink = self.comp.sink(self.solid(st), full, st.gap, self.dt, self.grid)
        if full.all():
            if sink is None or not np.any(sink.coeff > 0):
                return None
            if force_control and F_lim / self.case.area_mould <= float(sink.threshold.min()):
                return Rates(F_lim, 0.0, None)  # every cell bears F / A: the press rests
        # under force control the ram follows the force: its own speed does not enter
        free, beta = (0.0, 0.0) if force_control else self.ram_speed(st.t)
        try:
            if force_control or (beta == 0.0 and self.inv_k == 0.0):
                speed, force = (None, F_lim) if force_control else (free, None)
                sol = solve_pressure(self.grid, st.h / st.gap, self.fluidity(st), speed, force, self.guess,
                                     self.speed_guess, sink=sink, speed_floor=1e-6 * c.speed)
            else:
                sol = self._loaded(st, sink, free, beta)
        except SolverError:
            if not force_control or sink is None:
                raise
            sol = self._force_by_speed(st, sink)
            if sol is None:
                return Rates(F_lim, 0.0, None)
        self.guess, self.speed_guess = sol.p, sol.speed
        if force_control:
            return Rates(F_lim, sol.speed, sol, sink)
        ram = free * (1.0 - beta * sol.force / F_lim)
        if sink is None:
            return Rates(sol.force, sol.speed, sol, sink, ram)
        return Rates(sol.force - self._lag(st, sol, sink), sol.speed, sol, sink, ram)

    def ram_speed(self, t: float) -> tuple[float, float]:
        """The ram's free speed (m/s) at ``t`` (s) and its load slowdown (-): the set speed
        (or the measured ram profile's) and 0 without ``speed_ramp``.  At least a millionth
        of the set speed: a ram at rest (``speed_ramp`` at first contact, a pause in a
        profile) leaves no pressure to solve for."""
        if self.charge is None:
            free, beta = float(self.case.set_speed(np.array([t]))[0]), 0.0
        else:
            free, beta = self.charge.ram_speed(t)
        return max(free, 1e-6 * self.case.speed), beta

    def _loaded(self, st: State, sink: CompactionSink | None, free: float, beta: float) -> PressureSolution:
        """Speed control by a ram that slows under load or a frame that deflects, balanced
        over the step :attr:`dt` from the state's deflection
        (:func:`~smcbayes.forward.speeds2d.loaded_speed`)."""
        fluidity, floor = self.fluidity(st), 1e-6 * self.case.speed
        balance = Balance(free, beta, self.case.force_limit, self.inv_k, st.delta, self.dt)
        start = free if self.speed_guess is None else min(max(self.speed_guess, floor), free)
        return loaded_speed(lambda V: self._speed_solve(st, sink, V, fluidity), balance, start, floor,
                            self.case.id)

    def _speed_solve(self, st: State, sink: CompactionSink | None, V: float,
                     fluidity: Fluidity | None = None) -> PressureSolution:
        fluidity = self.fluidity(st) if fluidity is None else fluidity
        sol = solve_pressure(self.grid, st.h / st.gap, fluidity, V, None, self.guess, sink=sink)
        self.guess = sol.p
        return sol

    def _force_by_speed(self, st: State, sink: CompactionSink) -> PressureSolution | None:
        """Force control by the closing speed (:func:`~smcbayes.forward.speeds2d.speed_for_force`)."""
        return speed_for_force(lambda V: self._speed_solve(st, sink, V), self.speed_guess or self.case.speed,
                               1e-6 * self.case.speed, self.case.force_limit, self.case.id)

    def _lag(self, st: State, sol: PressureSolution, sink: CompactionSink) -> float:
        """Implicit part of the force (N): sum of dt s P_c'(s) c over the compacting cells.

        The semi-implicit pressure of a compacting cell is that of the end of the step;
        without this part the force is the compaction law's at the start of the step, the
        instant the node is recorded at.
        """
        c = sol.sink / (st.gap * self.grid.cell_area)
        lag = self.dt * sink.stiffness * c
        return self.grid.multiplicity * self.grid.cell_area * float(np.minimum(lag, sol.p).sum())

    def record(self, st: State, force: float) -> None:
        """Append a node (and snapshots when the filled area passes the next mark)."""
        r = self.run
        if len(r.t) >= MAX_NODES:
            raise SolverError(f"configuration '{self.case.id}': the 2-D run needs "
                              f"more than {MAX_NODES} steps")
        area, bulk, solid, solid_volume = self.measure(st)
        for name, value in (("t", st.t), ("gap", st.gap), ("area", area), ("force", force),
                            ("deflection", force * self.inv_k), ("volume", bulk), ("solid", solid),
                            ("solid_volume", solid_volume)):
            getattr(r, name).append(value)
        while self.snap_area and area >= self.snap_area[0] * (1.0 - 1e-9):
            self.snap_area.pop(0)
            r.snap_t.append(st.t)
            r.snap_f.append(np.minimum(st.h / st.gap, 1.0))
            r.snap_s.append(np.where(st.h > 0.0, self.solid(st), np.nan))

    def advance(self, st: State, r: Rates, dt: float) -> State:
        """State after ``dt`` (s): filled cells lose V dt, front cells gain their inflow,
        the solid moves with the face fluxes, the excess spills.

        The frame's deflection grows by the ram's travel less the gap's, (U - V) dt; over
        the step the balance was solved for that is F / k, and over a shorter one (a step
        cut to land on a fill or the limit) it keeps the ram's position exact.
        """
        gap = max(st.gap - r.speed * dt, self.gap_end)
        extra = st.extra if self.charge is None else self.charge.advance(st.extra, st.gap, dt)
        delta = 0.0
        if self.inv_k > 0.0:
            delta = self.case.force_limit * self.inv_k if r.ram is None else max(
                st.delta + (r.ram - r.speed) * dt, 0.0)
        if r.sol is None:
            return State(st.t + dt, gap, st.h, st.sigma, extra, delta)
        full = st.h >= st.gap * FULL
        h = np.where(full, st.h - r.speed * dt, st.h + r.sol.inflow * dt / self.grid.cell_area)
        if self.comp is None:
            h = spill_with(h, gap, None)[0]
            return State(st.t + dt, gap, h, h, extra, delta)
        sigma = st.sigma + solid_inflow(r.sol, self.solid(st)) * dt / self.grid.cell_area
        h, sigma = spill_with(h, gap, sigma, absorb=True)
        if float(np.sum(gap - h)) <= SNAP * gap:
            # the last open capacity is round-off of the semi-implicit compaction: call the
            # cavity full (the solid stays; s of the last cells drops by at most SNAP)
            h = np.full_like(h, gap)
        return State(st.t + dt, gap, h, sigma, extra, delta)

    def step_size(self, st: State, r: Rates, dt_max: float) -> float:
        """Largest step (s) within :meth:`regular_step`, the filling of the cavity and the
        end gap."""
        dt, sol = self.regular_step(st, r, dt_max), r.sol
        if sol is not None and not np.all(st.h >= st.gap * FULL):
            # land on the instant the cavity fills: mean content = gap
            mean = float(st.h.mean())
            closing = r.speed - float(sol.sink.sum()) / (st.h.size * self.grid.cell_area)
            if closing > 0:
                dt = min(dt, (st.gap - mean) / closing)
        return min(dt, (st.gap - self.gap_end) / r.speed) if r.speed > 0 else dt

    def regular_step(self, st: State, r: Rates, dt_max: float) -> float:
        """Largest step (s) within ``dt_max``, the front Courant limit and, with pores, the
        stability limit of the solid transport and the compaction limits (:data:`LAG`,
        :data:`PORE_STEP`)."""
        dt, g, sol = dt_max, self.grid, r.sol
        if sol is not None and sol.inflow.max() > 0:
            dt = min(dt, self.o.courant * st.gap * g.cell_area / float(sol.inflow.max()))
        if sol is not None and self.comp is not None:
            out = largest_outflow(sol, st.h.shape)
            if out > 0:  # stability of the upwind solid transport
                dt = min(dt, 0.9 * st.gap * g.cell_area / out)
            s = self.solid(st)
            c = sol.sink / (st.gap * g.cell_area)  # volumetric compaction rate (1/s)
            if c.max() > 0:
                on = c > 0
                dt = min(dt, PORE_STEP * self.refine * float(np.min((1.0 - s[on]) / (s[on] * c[on]))))
                if r.sink is not None:  # lag error dt s P_c' c below LAG of the cell pressure
                    floor = 0.01 * self.case.force_limit / self.case.area_mould
                    err = r.sink.stiffness[on] * c[on]
                    ok = err > 0
                    if ok.any():
                        bound = np.maximum(sol.p[on][ok], floor) / err[ok]
                        dt = min(dt, LAG * self.refine * float(np.min(bound)))
        return dt

    def sized(self, st: State, r: Rates, dt_max: float, force_control: bool) -> tuple[float, Rates | None]:
        """Step size at ``st`` and the rates solved for it (again if the step was cut).

        The next pressure solve assumes a step of 1.1 times this one's regular limit (at
        most ``dt_max``): those limits change slowly, so a cut rarely needs a second solve,
        and a one-off cut (landing on the filled cavity) does not shrink the next steps.
        """
        dt = self.step_size(st, r, dt_max)
        if (self.comp is not None or self.inv_k > 0.0) and dt < RETRY * self.dt:
            self.dt = dt
            r2 = self.rates(st, force_control)
            if r2 is None:
                return dt, None
            # the frame's balance over the shorter step changes the closing speed, so the
            # step that lands on the filled cavity is the re-solved speed's
            again = self.step_size(st, r2, dt_max)
            r, dt = r2, (again if self.inv_k > 0.0 else min(dt, again))
        self.dt = min(dt_max, 1.1 * self.regular_step(st, r, dt_max))
        return dt, r

    def speed_phase(self, st: State) -> tuple[State, Rates | None]:
        """Speed control until the force limit (returns the state and its rates there) or
        until the charge fills the cavity for good (returns the final state and None)."""
        case, press = self.case, self.press
        r = self.rates(st, False)
        while r is not None and not press.reaches_limit(r.force):
            if case.profile is not None and bool(case.profile.ends_at_rest(st.t)):
                raise SolverError(f"configuration '{case.id}': {AT_REST}")
            dt, r2 = self.sized(st, r, self.dt_max, False)
            r = r2 if r2 is not None else r
            self.record(st, r.force)
            new = self.advance(st, r, dt)
            new_r = self.rates(new, False)
            if new_r is None:  # full: the gap stops and the ram loads the frame to the limit
                self.record(new, r.force)
                self.run.switch = new.t + self._frame_loading(new.t, r.force)
                self.hold(new, self.run.switch)
                return new, None
            if press.reaches_limit(new_r.force) and self.comp is not None:
                # the force there depends on the step of the semi-implicit compaction
                new_r = self.sized(new, new_r, self.dt_max, False)[1] or new_r
            if press.reaches_limit(new_r.force):
                if np.all(new.h >= new.gap * FULL) and not np.all(st.h >= st.gap * FULL):
                    st, r = new, new_r  # the limit comes with the filling of the cavity
                else:
                    st, r = self._locate_switch(st, r, dt, new_r)
                break
            st, r = new, new_r
        if r is None:
            raise SolverError(f"configuration '{case.id}': the charge fills the cavity at first contact")
        self.run.switch = st.t
        self.record(st, press.force_limit)
        return st, r

    def _frame_loading(self, t: float, force: float) -> float:
        """Time (s) from the fill of the cavity at ``t`` (s), at ``force`` (N), to the force
        limit: the gap stops, the ram runs on and loads the frame (a jump on a rigid one;
        :func:`~smcbayes.forward.programme.load_travel`), at its free speed at the fill or
        along the measured profile with the speed ramp's factor at the fill held, as in the
        1-D solver, which starts from the load of the frame's deflection
        (:func:`~smcbayes.forward.programme.frame_load`) where this starts from
        ``force``."""
        case, jump = self.case, self.press.jump_time
        free, beta = self.ram_speed(t)
        if case.profile is None:
            return float(load_time(force, case.force_limit, self.inv_k, free, beta, jump))
        # the speed ramp's factor on the log's speed at the fill, held
        factor = free / max(float(case.set_speed(np.array([t]))[0]), 1e-6 * case.speed)
        travel = float(load_travel(force, case.force_limit, self.inv_k, beta)) / max(factor, 1e-6)
        end = case.profile.time_after(t, travel)
        if not np.isfinite(end):
            raise SolverError(f"configuration '{case.id}': {AT_REST}")
        return max(end - t, jump)

    def _locate_switch(self, st: State, r: Rates, dt: float, hi: Rates) -> tuple[State, Rates]:
        """Step from ``st`` that lands on the force limit (regula falsi in the step size)."""
        F_lim = self.case.force_limit
        lo_dt, lo_F, hi_dt, hi_F = 0.0, r.force, dt, hi.force
        new, new_r = self.advance(st, r, dt), hi
        for _ in range(6):
            trial = lo_dt + (F_lim - lo_F) / (hi_F - lo_F) * (hi_dt - lo_dt)
            new = self.advance(st, r, trial)
            new_r = self.rates(new, False)
            if new_r is None:
                raise SolverError(f"configuration '{self.case.id}': cavity filled while locating "
                                  "the force limit")
            if abs(new_r.force - F_lim) <= 1e-4 * F_lim:
                break
            if new_r.force < F_lim:
                lo_dt, lo_F = trial, new_r.force
            else:
                hi_dt, hi_F = trial, new_r.force
        return new, new_r

    def force_phase(self, st: State) -> None:
        """Force control from the switch state for the hold time."""
        case, run = self.case, self.run
        t_end = run.switch + self.press.hold
        dH = max(st.gap - self.gap_end, 0.0) / self.o.hold_steps
        r = self.rates(st, True)
        while r is not None and st.t < t_end:
            limit = min(dH / r.speed if r.speed > 0 else np.inf, t_end - st.t)
            dt, r2 = self.sized(st, r, limit, True)
            r = r2 if r2 is not None else r
            st = self.advance(st, r, min(dt, limit))
            r = self.rates(st, True)
            self.record(st, case.force_limit)
        self.hold(st, t_end)

    def hold(self, st: State, t_end: float) -> None:
        """Close the record with the force limit held until ``t_end`` (s)."""
        if t_end > self.run.t[-1] or self.run.force[-1] != self.case.force_limit:
            self.record(State(max(t_end, self.run.t[-1]), st.gap, st.h, st.sigma, st.extra),
                        self.case.force_limit)
        if self.run.t[-1] < self.run.switch + self.press.hold:
            self.record(State(self.run.switch + self.press.hold, st.gap, st.h, st.sigma, st.extra),
                        self.case.force_limit)
