"""2-D thin-cavity reference solver (``hele_shaw2d``) for arbitrary charge layouts.

Generalised Hele-Shaw flow with wall slip on the mould plane (design 4.2), solved by
finite volumes on a structured grid with a fill-fraction (control-volume) flow front:

* every cell carries the charge thickness h = f H it holds (f the fill fraction);
* filled cells (f = 1) carry the pressure, div(S(|grad p|) grad p) = -V, front cells have
  p = 0 and mould walls no flux (:mod:`smcbayes.forward.grid2d`);
* front cells gain the volume flowing in from filled cells, filled cells lose V per unit
  area; a cell whose content exceeds the gap passes the excess on to its neighbours, so
  the charge volume is conserved to round-off;
* the press protocol is the 1-D solver's: speed control at the set speed until the force
  limit (located inside a step by secant refinement), then force control (the closing
  speed that gives F = F_limit, solved together with the pressure) for the hold time; an
  incompressible charge that fills the cavity stops the press and the force jumps to the
  limit.

Mirror symmetry of the layout about the mould's centre lines is used to solve a half or a
quarter of the mould.  Parameter sets are solved one after another.

The base (isothermal, incompressible) model is supported; effects are not (use the 1-D
solver for them).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np
from numpy.typing import NDArray
from scipy import ndimage

from smcbayes.config import MaterialSpec, SolverSpec
from smcbayes.errors import ConfigError, SolverError
from smcbayes.forward.case import Case
from smcbayes.forward.effects.base import EffectStack
from smcbayes.forward.flux import MaterialTable, log_grid
from smcbayes.forward.grid2d import FULL, Fluidity, Grid, PressureSolution, solve_pressure
from smcbayes.forward.layout import coverage, symmetric
from smcbayes.forward.nodes import Nodes, to_result
from smcbayes.forward.result import STATUS_OK, SimulationResult
from smcbayes.forward.squeeze1d import material_table

Array = NDArray[np.float64]


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
        jump_time_s: time for the force to reach the limit once the cavity is full.
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
class FillHistory:
    """Fill-fraction fields of one run over the whole mould.

    Attributes:
        time_s: snapshot times (s), ``(K,)``.
        fill: fill fraction per cell, ``(K, NX, NY)`` (NX along the mould length).
        x_faces_mm, y_faces_mm: cell faces of the whole mould relative to its centre (mm).
    """

    time_s: Array
    fill: Array
    x_faces_mm: Array
    y_faces_mm: Array


@dataclass
class _State:
    """State of one run: time (s), gap (m), charge thickness per cell (m), ``(nx, ny)``."""

    t: float
    gap: float
    h: Array


@dataclass
class _Run:
    """Node record of one parameter set."""

    t: list[float] = field(default_factory=list)
    gap: list[float] = field(default_factory=list)
    area: list[float] = field(default_factory=list)
    force: list[float] = field(default_factory=list)
    volume: list[float] = field(default_factory=list)
    snap_t: list[float] = field(default_factory=list)
    snap_f: list[Array] = field(default_factory=list)
    switch: float = 0.0


def make_grid(case: Case, cells: int, use_symmetry: bool) -> tuple[Grid, Array]:
    """Grid of the solved part of the mould and its initial charge thickness (m).

    Returns:
        ``(grid, h0)``; ``h0`` has shape ``(grid.nx, grid.ny)``.
    """
    L, W = case.mould_length, case.width
    n_long = 2 * int(np.ceil(cells / 2))
    nx = n_long if L >= W else 2 * max(1, int(round(n_long * L / W / 2)))
    ny = n_long if W > L else 2 * max(1, int(round(n_long * W / L / 2)))
    xf, yf = np.linspace(-L / 2, L / 2, nx + 1), np.linspace(-W / 2, W / 2, ny + 1)
    cover = coverage(case.pieces, xf, yf)
    mult = 1
    if use_symmetry and symmetric(cover, 0):
        cover, xf, mult = cover[nx // 2:], xf[nx // 2:], mult * 2
    if use_symmetry and symmetric(cover, 1):
        cover, yf, mult = cover[:, ny // 2:], yf[ny // 2:], mult * 2
    grid = Grid(cover.shape[0], cover.shape[1], L / nx, W / ny, xf, yf, mult)
    return grid, cover / grid.cell_area * case.gap0


def whole_mould(grid: Grid, fill: Array) -> tuple[Array, Array, Array]:
    """Mirror a half/quarter field onto the whole mould: ``(fill, x_faces, y_faces)``."""
    xf, yf = grid.x_faces, grid.y_faces
    if xf[0] > -1e-12 and grid.multiplicity > 1 and not np.isclose(-xf[-1], xf[0]):
        fill = np.concatenate([np.flip(fill, 0), fill], axis=0)
        xf = np.concatenate([-np.flip(xf[1:]), xf])
    if yf[0] > -1e-12 and grid.multiplicity > 1 and not np.isclose(-yf[-1], yf[0]):
        fill = np.concatenate([np.flip(fill, 1), fill], axis=1)
        yf = np.concatenate([-np.flip(yf[1:]), yf])
    return fill, xf, yf


def spill(h: Array, gap: float) -> Array:
    """Pass the content above ``gap`` on to the nearest non-filled cells (m).

    Excess moves one cell per pass down the taxicab distance to the nearest open cell
    (equal shares between the neighbours one step closer), so it reaches the front in as
    many passes as it is cells away.  The total is conserved exactly.
    """
    h = h.copy()
    nx, ny = h.shape
    shifts = ((0, 1), (2, 1), (1, 0), (1, 2))  # neighbour (i + a - 1, j + b - 1)
    for _ in range(4 * (nx + ny) + 10):
        excess = np.where(h > gap * (1.0 + 1e-11), h - gap, 0.0)
        if not excess.any():  # round-off of filled cells stays in place
            return h
        open_ = h < gap * FULL
        if not open_.any():
            if excess.sum() <= 1e-9 * h.sum():
                return h - excess  # cavity full: what is left over is round-off
            raise SolverError("2-D fill update: the charge holds more volume than the cavity")
        dist = ndimage.distance_transform_cdt(~open_, metric="taxicab").astype(float)
        pad = np.pad(dist, 1, constant_values=np.inf)
        targets = [pad[a:a + nx, b:b + ny] == dist - 1.0 for a, b in shifts]
        count = sum(t.astype(float) for t in targets)
        share = excess / np.maximum(count, 1.0)
        gained = np.zeros((nx + 2, ny + 2))
        for (a, b), t in zip(shifts, targets):
            gained[a:a + nx, b:b + ny] += np.where(t, share, 0.0)
        h += gained[1:-1, 1:-1] - excess
    raise SolverError("2-D fill update: overflow could not be redistributed")


class HeleShaw2D:
    """The 2-D solver plug-in: ``solve(case, params, effects, material) -> result``."""

    name: ClassVar[str] = "2d"

    def __init__(self, options: HeleShaw2DOptions | None = None) -> None:
        self.options = options or HeleShaw2DOptions()
        o = self.options
        self.tau = log_grid(o.tau_min_Pa, o.tau_max_Pa, o.per_decade)
        self.fields: dict[str, list[FillHistory]] = {}
        """Fill-fraction snapshots of the last run, per configuration id and row."""

    @classmethod
    def from_spec(cls, spec: SolverSpec) -> HeleShaw2D:
        """Solver with the project's discretisation."""
        return cls(HeleShaw2DOptions(
            cells=getattr(spec, "cells_2d", 48), courant=getattr(spec, "courant_2d", 0.5),
            closing_steps=getattr(spec, "closing_steps_2d", 100),
            hold_steps=getattr(spec, "hold_steps_2d", 40),
            per_decade=spec.stress_points_per_decade,
            output_closing_points=spec.output_closing_points,
            output_hold_points=spec.output_hold_points))

    def solve(self, case: Case, p: dict[str, Array], effects: EffectStack,
              material: MaterialSpec) -> SimulationResult:
        """Simulate one configuration for a batch of parameter sets (one after another).

        Args:
            case: the configuration in SI (``case.pieces`` holds the charge layout).
            p: SI parameters by symbol, each ``(P,)``.
            effects: the enabled effects; must be empty (base model only).
            material: slip coefficient and threshold exponent.
        """
        if effects.effects:
            raise ConfigError(f"the 2-D solver runs the base model only; switch off the effects "
                              f"{', '.join(effects.names)} or use --fidelity 1d")
        if case.profile is not None:
            raise ConfigError(f"configuration '{case.id}': the 2-D solver needs a constant set "
                              "speed; remove press.profile or use --fidelity 1d")
        table = material_table(p, material, self.tau)
        rows = p["n"].shape[0]
        runs = [self.run_row(case, table, float(p["B"][r]), r) for r in range(rows)]
        grid, _ = make_grid(case, self.options.cells, self.options.use_symmetry)
        self.fields[case.id] = [self._history(grid, run) for run in runs]
        nodes = _to_nodes(runs)
        o = self.options
        return to_result(case, nodes, o.output_closing_points, o.output_hold_points, ())

    def _history(self, grid: Grid, run: _Run) -> FillHistory:
        fills = [whole_mould(grid, f)[0] for f in run.snap_f]
        _, xf, yf = whole_mould(grid, run.snap_f[0])
        return FillHistory(np.array(run.snap_t), np.array(fills), xf * 1e3, yf * 1e3)

    def run_row(self, case: Case, table: MaterialTable, eta0: float, row: int) -> _Run:
        """Simulate one parameter set (row ``row`` of ``table``); returns its node record."""
        o = self.options
        grid, h0 = make_grid(case, o.cells, o.use_symmetry)
        law = _Law(self.tau, table.slip[row], table.shear[row] / (2.0 * eta0 * self.tau**2))
        stepper = _Stepper(case, grid, law, o)
        state, sol = stepper.speed_phase(_State(0.0, case.gap0, h0))
        if sol is not None:
            stepper.force_phase(state, sol)
        return stepper.run


@dataclass
class _Law:
    """Flux law of one parameter set: q(tau) = H slip + H^2 coeff (m^2/s), ``(M,)``."""

    tau: Array
    slip: Array
    coeff: Array

    def at(self, gap: float) -> Fluidity:
        return Fluidity(self.tau, gap * self.slip + gap * gap * self.coeff, gap)


class _Stepper:
    """Time stepping of one parameter set through the press protocol."""

    def __init__(self, case: Case, grid: Grid, law: _Law, options: HeleShaw2DOptions) -> None:
        self.case, self.grid, self.law, self.o = case, grid, law, options
        self.run = _Run()
        self.guess: Array | None = None
        self.speed_guess: float | None = None
        area0 = case.area0 * case.gap0
        self.snap_area = list(np.linspace(area0 / case.gap0, case.area_mould, options.snapshots))
        self._area_full = area0 / case.gap_full

    def solve(self, st: _State, speed: float | None) -> PressureSolution | None:
        """Pressure at state ``st`` (speed or force control); None once the cavity is full."""
        fill = st.h / st.gap
        if np.all(fill >= FULL):
            return None
        sol = solve_pressure(self.grid, fill, self.law.at(st.gap), speed,
                             None if speed is not None else self.case.force_limit,
                             self.guess, self.speed_guess)
        self.guess, self.speed_guess = sol.p, sol.speed
        return sol

    def record(self, st: _State, force: float) -> None:
        """Append a node (and a fill snapshot when the filled area passes the next mark)."""
        g, r = self.grid, self.run
        fill = np.minimum(st.h / st.gap, 1.0)
        area = g.multiplicity * g.cell_area * float(fill.sum())
        r.t.append(st.t)
        r.gap.append(st.gap)
        r.area.append(area)
        r.force.append(force)
        r.volume.append(g.multiplicity * g.cell_area * float(st.h.sum()))
        while self.snap_area and area >= self.snap_area[0] * (1.0 - 1e-9):
            self.snap_area.pop(0)
            r.snap_t.append(st.t)
            r.snap_f.append(fill.copy())

    def advance(self, st: _State, sol: PressureSolution, dt: float) -> _State:
        """State after ``dt`` (s) at the speed and inflows of ``sol``."""
        gap = max(st.gap - sol.speed * dt, self.case.gap_full)
        full = st.h >= st.gap * FULL
        h = np.where(full, st.h - (st.gap - gap), st.h + sol.inflow * dt / self.grid.cell_area)
        return _State(st.t + dt, gap, spill(h, gap))

    def step_size(self, st: _State, sol: PressureSolution, dt_max: float) -> float:
        """Largest step (s) within the front Courant limit, ``dt_max`` and the fill gap."""
        rate = float(sol.inflow.max()) / self.grid.cell_area
        dt = dt_max if rate <= 0 else min(dt_max, self.o.courant * st.gap / rate)
        return min(dt, (st.gap - self.case.gap_full) / sol.speed)

    def speed_phase(self, st: _State) -> tuple[_State, PressureSolution | None]:
        """Speed control until the force limit (returns the state and its solve there) or
        until the cavity is full (returns the final state and None)."""
        case = self.case
        dt_max = (case.gap0 - case.gap_full) / (case.speed * self.o.closing_steps)
        sol = self.solve(st, case.speed)
        while sol is not None and sol.force < case.force_limit:
            self.record(st, sol.force)
            dt = self.step_size(st, sol, dt_max)
            new = self.advance(st, sol, dt)
            new_sol = self.solve(new, case.speed)
            if new_sol is None:  # full: the force jumps to the limit
                self.record(new, sol.force)
                self.run.switch = new.t + self.o.jump_time_s
                self._hold(new, self.run.switch)
                return new, None
            if new_sol.force >= case.force_limit:
                st, sol = self._locate_switch(st, sol, dt, new_sol)
                break
            st, sol = new, new_sol
        if sol is None:
            raise SolverError(f"configuration '{case.id}': the charge fills the cavity at first contact")
        self.run.switch = st.t
        self.record(st, case.force_limit)
        return st, sol

    def _locate_switch(self, st: _State, sol: PressureSolution, dt: float,
                       hi: PressureSolution) -> tuple[_State, PressureSolution]:
        """Step from ``st`` that lands on the force limit (regula falsi in the step size)."""
        F_lim = self.case.force_limit
        lo_dt, lo_F, hi_dt, hi_F = 0.0, sol.force, dt, hi.force
        new, new_sol = self.advance(st, sol, dt), hi
        for _ in range(6):
            trial = lo_dt + (F_lim - lo_F) / (hi_F - lo_F) * (hi_dt - lo_dt)
            new = self.advance(st, sol, trial)
            new_sol = self.solve(new, self.case.speed)
            if new_sol is None:
                raise SolverError(f"configuration '{self.case.id}': cavity filled while locating the force limit")
            if abs(new_sol.force - F_lim) <= 1e-4 * F_lim:
                break
            if new_sol.force < F_lim:
                lo_dt, lo_F = trial, new_sol.force
            else:
                hi_dt, hi_F = trial, new_sol.force
        return new, new_sol

    def force_phase(self, st: _State, sol: PressureSolution) -> None:
        """Force control from the switch state for the hold time (or until full)."""
        case, run = self.case, self.run
        t_end = run.switch + case.hold
        dH = max(st.gap - case.gap_full, 0.0) / self.o.hold_steps
        current: PressureSolution | None = self.solve(st, None)
        while current is not None and st.t < t_end:
            dt = min(self.step_size(st, current, np.inf), dH / current.speed, t_end - st.t)
            st = self.advance(st, current, dt)
            self.record(st, case.force_limit)
            current = self.solve(st, None)
        self._hold(st, t_end)

    def _hold(self, st: _State, t_end: float) -> None:
        """Close the record with the force limit held until ``t_end`` (s)."""
        end = max(t_end, self.run.t[-1])
        self.record(_State(end, st.gap, st.h), self.case.force_limit)
        if self.run.t[-1] < self.run.switch + self.case.hold:
            self.record(_State(self.run.switch + self.case.hold, st.gap, st.h), self.case.force_limit)


def _to_nodes(runs: list[_Run]) -> Nodes:
    """Stack the node records of all rows, padding each past its end."""
    P, S = len(runs), max(len(r.t) for r in runs)
    out = {k: np.zeros((P, S)) for k in ("t", "gap", "area", "force")}
    count = np.zeros(P, dtype=np.int64)
    for i, r in enumerate(runs):
        n = len(r.t)
        count[i] = n
        for key, vals in (("t", r.t), ("gap", r.gap), ("area", r.area), ("force", r.force)):
            arr = np.asarray(vals, dtype=float)
            out[key][i, :n] = arr
            out[key][i, n:] = arr[-1]
    return Nodes(time=out["t"], gap=out["gap"], area=out["area"], force=out["force"],
                 deflection=np.zeros((P, S)), solid=np.ones((P, S)), count=count,
                 switch=np.array([r.switch for r in runs]), status=[STATUS_OK] * P)
