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

The base model and the ``compressibility`` effect are supported (lumped compaction: one
solid fraction for the whole charge, the closing speed split between spreading and pore
compaction under the common mean pressure, as in the 1-D solver); other effects are not.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np
from numpy.typing import NDArray

from smcbayes.config import MaterialSpec, SolverSpec
from smcbayes.errors import ConfigError, SolverError
from smcbayes.forward.case import Case
from smcbayes.forward.effects.base import EffectStack
from smcbayes.forward.flux import MaterialTable, log_grid
from smcbayes.forward.grid2d import FULL, Fluidity, Grid, PressureSolution, solve_pressure, spill
from smcbayes.forward.layout import coverage, symmetric
from smcbayes.forward.nodes import Nodes, to_result
from smcbayes.forward.result import STATUS_OK, SimulationResult
from smcbayes.forward.squeeze1d import material_table

Array = NDArray[np.float64]
SUPPORTED_EFFECTS = ("compressibility",)


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
    solid: list[float] = field(default_factory=list)
    snap_t: list[float] = field(default_factory=list)
    snap_f: list[Array] = field(default_factory=list)
    switch: float = 0.0
    status: str = STATUS_OK


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
            cells=spec.cells_2d, courant=spec.courant_2d, closing_steps=spec.closing_steps_2d,
            hold_steps=spec.hold_steps_2d,
            per_decade=spec.stress_points_per_decade,
            output_closing_points=spec.output_closing_points,
            output_hold_points=spec.output_hold_points))

    def solve(self, case: Case, p: dict[str, Array], effects: EffectStack,
              material: MaterialSpec) -> SimulationResult:
        """Simulate one configuration for a batch of parameter sets (one after another).

        Args:
            case: the configuration in SI (``case.pieces`` holds the charge layout).
            p: SI parameters by symbol, each ``(P,)``.
            effects: the enabled effects: none, or ``compressibility`` (lumped pore
                compaction of the whole charge).
            material: slip coefficient and threshold exponent.
        """
        other = [n for n in effects.names if n not in SUPPORTED_EFFECTS]
        if other:
            raise ConfigError(f"the 2-D solver supports the effects {', '.join(SUPPORTED_EFFECTS)} only; "
                              f"switch off {', '.join(other)} or use --fidelity 1d")
        if case.profile is not None:
            raise ConfigError(f"configuration '{case.id}': the 2-D solver needs a constant set "
                              "speed; remove press.profile or use --fidelity 1d")
        table = material_table(p, material, self.tau)
        rows = p["n"].shape[0]
        runs = []
        for r in range(rows):
            # one parameter set that fails must not take the other rows of the batch with it
            try:
                runs.append(self.run_row(case, table, float(p["B"][r]), r, _compaction(case, p, effects, r)))
            except SolverError as err:
                runs.append(_Run(t=[0.0, 1.0], gap=[case.gap0] * 2, area=[case.area0] * 2,
                                 force=[0.0, 0.0], solid=[1.0, 1.0], switch=1.0, status=f"failed: {err}"))
        grid, _ = make_grid(case, self.options.cells, self.options.use_symmetry)
        self.fields[case.id] = [self._history(grid, run) if run.snap_f else None for run in runs]
        nodes = _to_nodes(runs)
        o = self.options
        return to_result(case, nodes, o.output_closing_points, o.output_hold_points,
                         tuple(effects.names))

    def _history(self, grid: Grid, run: _Run) -> FillHistory:
        fills = [whole_mould(grid, f)[0] for f in run.snap_f]
        _, xf, yf = whole_mould(grid, run.snap_f[0])
        return FillHistory(np.array(run.snap_t), np.array(fills), xf * 1e3, yf * 1e3)

    def run_row(self, case: Case, table: MaterialTable, eta0: float, row: int,
                compaction: _Compaction | None = None) -> _Run:
        """Simulate one parameter set (row ``row`` of ``table``); returns its node record."""
        o = self.options
        grid, h0 = make_grid(case, o.cells, o.use_symmetry)
        law = _Law(self.tau, table.slip[row], table.shear[row] / (2.0 * eta0 * self.tau**2))
        stepper = _Stepper(case, grid, law, o, compaction)
        state, rates = stepper.speed_phase(_State(0.0, case.gap0, h0))
        if rates is not None:
            stepper.force_phase(state)
        return stepper.run


def _compaction(case: Case, p: dict[str, Array], effects: EffectStack, row: int) -> _Compaction | None:
    """Lumped compaction of row ``row`` from the effects' hooks, or None (no pores)."""
    s0 = effects.solid_fraction0(case, p, p["n"].shape[0])
    if s0 is None or float(np.asarray(s0)[row]) >= 1.0:
        return None
    p_row = {k: np.asarray(v)[row:row + 1] for k, v in p.items()}

    def law(solid: float) -> tuple[float, float]:
        pc, zeta = effects.compaction(case, p_row, np.array([solid]))
        return float(np.asarray(pc).ravel()[0]), float(np.asarray(zeta).ravel()[0])

    return _Compaction(float(np.asarray(s0)[row]), case.area0 * case.gap0, law)


@dataclass
class _Law:
    """Flux law of one parameter set: q(tau) = H slip + H^2 coeff (m^2/s), ``(M,)``."""

    tau: Array
    slip: Array
    coeff: Array

    def at(self, gap: float) -> Fluidity:
        return Fluidity(self.tau, gap * self.slip + gap * gap * self.coeff, gap)


@dataclass(frozen=True)
class _Compaction:
    """Lumped pore compaction of one parameter set.

    Attributes:
        solid0: initial solid fraction s0 (< 1).
        bulk0: initial charge volume, pores included (m^3).
        law: solid fraction -> (compaction pressure P_c (Pa), bulk viscosity (Pa s)).
    """

    solid0: float
    bulk0: float
    law: Callable[[float], tuple[float, float]]


@dataclass
class _Rates:
    """Force (N), gap closing speed V and spreading speed V_s (m/s) at a state, with the
    flow solution at V_s (None when the cavity is full and nothing flows)."""

    force: float
    speed: float
    spread: float
    sol: PressureSolution | None


class _Stepper:
    """Time stepping of one parameter set through the press protocol.

    With a compressible charge the closing speed splits into spreading V_s (the 2-D flow)
    and compaction V_c = V - V_s of the whole charge under the mean pressure F / A:
    F / A = P_c(s) + zeta V_c / H while the pores compact, s = s0 bulk0 / bulk.
    """

    def __init__(self, case: Case, grid: Grid, law: _Law, options: HeleShaw2DOptions,
                 compaction: _Compaction | None) -> None:
        self.case, self.grid, self.law, self.o, self.comp = case, grid, law, options, compaction
        self.run = _Run()
        self.guess: Array | None = None
        self.speed_guess: float | None = None
        self.snap_area = list(np.linspace(case.area0, case.area_mould, options.snapshots))
        self.gap_end = case.gap_full * (1.0 if compaction is None else compaction.solid0)

    def measure(self, st: _State) -> tuple[float, float, float]:
        """Filled area (m^2), bulk volume (m^3) and solid fraction of a state."""
        g = self.grid
        area = g.multiplicity * g.cell_area * float(np.minimum(st.h / st.gap, 1.0).sum())
        bulk = g.multiplicity * g.cell_area * float(st.h.sum())
        solid = 1.0 if self.comp is None else min(self.comp.solid0 * self.comp.bulk0 / bulk, 1.0)
        return area, bulk, solid

    def flow(self, st: _State, speed: float | None, force: float | None) -> PressureSolution:
        """Pressure at state ``st`` for a spreading speed or a force."""
        sol = solve_pressure(self.grid, st.h / st.gap, self.law.at(st.gap), speed, force,
                             self.guess, self.speed_guess)
        self.guess, self.speed_guess = sol.p, sol.speed
        return sol

    def rates(self, st: _State, force_control: bool) -> _Rates | None:
        """Force and speeds at ``st``; None once an incompressible charge fills the cavity."""
        c, F_lim = self.case, self.case.force_limit
        area, _, solid = self.measure(st)
        pores = self.comp is not None and solid < 1.0 - 1e-9
        pc, zeta = self.comp.law(solid) if pores else (np.inf, 0.0)

        def creep(F: float) -> float:
            """Compaction speed under force F with the bulk viscosity (m/s)."""
            return max(F / area - pc, 0.0) * st.gap / zeta if zeta > 0 and np.isfinite(pc) else 0.0

        if np.all(st.h >= st.gap * FULL):
            if not np.isfinite(pc):
                return None
            if force_control:
                return _Rates(F_lim, creep(F_lim), 0.0, None)
            return _Rates(area * (pc + zeta * c.speed / st.gap), c.speed, 0.0, None)
        if force_control:
            sol = self.flow(st, None, F_lim)
            return _Rates(F_lim, sol.speed + creep(F_lim), sol.speed, sol)
        sol = self.flow(st, c.speed, None)
        if sol.force <= area * pc:
            return _Rates(sol.force, c.speed, c.speed, sol)
        if zeta > 0:
            return self._split(st, area, pc, zeta, sol)
        if area * pc <= 1e-9 * sol.force:  # pores give way before the charge flows at all
            return _Rates(0.0, c.speed, 0.0, None)
        sol = self.flow(st, None, area * pc)
        return _Rates(area * pc, c.speed, min(sol.speed, c.speed), sol)

    def _split(self, st: _State, area: float, pc: float, zeta: float,
               at_speed: PressureSolution) -> _Rates:
        """Force F in [A P_c, F(V)] where V_s(F) + (F/A - P_c) H / zeta = V.

        ``at_speed`` is the flow at V_s = V (force F(V) > A P_c).  The left side increases
        with F, is below V at A P_c (V_s < V, no compaction) and above it at F(V); Illinois
        regula falsi on the difference.
        """
        V = self.case.speed

        def excess(F: float) -> tuple[float, PressureSolution | None]:
            if F <= 0.0:
                return -V, None
            sol = self.flow(st, None, F)
            return sol.speed + (F / area - pc) * st.gap / zeta - V, sol

        lo, hi = area * pc, at_speed.force
        (g_lo, _), g_hi = excess(lo), (hi / area - pc) * st.gap / zeta
        F, sol, side = hi, at_speed, 0
        for _ in range(60):
            F = hi - g_hi * (hi - lo) / (g_hi - g_lo)
            val, sol = excess(F)
            if abs(val) <= 1e-6 * V or sol is None:
                break
            if val < 0:
                lo, g_lo, g_hi = F, val, g_hi / 2 if side == -1 else g_hi
                side = -1
            else:
                hi, g_hi, g_lo = F, val, g_lo / 2 if side == 1 else g_lo
                side = 1
        spread = 0.0 if sol is None else sol.speed
        return _Rates(F, V, spread, sol)

    def record(self, st: _State, force: float) -> None:
        """Append a node (and a fill snapshot when the filled area passes the next mark)."""
        r = self.run
        area, bulk, solid = self.measure(st)
        for name, value in (("t", st.t), ("gap", st.gap), ("area", area), ("force", force),
                            ("volume", bulk), ("solid", solid)):
            getattr(r, name).append(value)
        while self.snap_area and area >= self.snap_area[0] * (1.0 - 1e-9):
            self.snap_area.pop(0)
            r.snap_t.append(st.t)
            r.snap_f.append(np.minimum(st.h / st.gap, 1.0))

    def advance(self, st: _State, r: _Rates, dt: float) -> _State:
        """State after ``dt`` (s): uniform compaction, then spreading by the inflows of ``r``."""
        gap = max(st.gap - r.speed * dt, self.gap_end)
        h = st.h * (1.0 - (r.speed - r.spread) * dt / st.gap)
        if r.sol is not None:
            full = st.h >= st.gap * FULL
            h = np.where(full, h - r.spread * dt, h + r.sol.inflow * dt / self.grid.cell_area)
        return _State(st.t + dt, gap, spill(h, gap))

    def step_size(self, st: _State, r: _Rates, dt_max: float) -> float:
        """Largest step (s) within the front Courant limit, ``dt_max``, the filling of the
        cavity, the end gap and a quarter of the remaining pore fraction."""
        dt = dt_max
        if r.sol is not None and r.sol.inflow.max() > 0:
            dt = min(dt, self.o.courant * st.gap * self.grid.cell_area / float(r.sol.inflow.max()))
        if r.sol is not None:  # land on the instant the cavity fills: mean content = gap
            mean = float(st.h.mean())
            closing = r.speed - mean * (r.speed - r.spread) / st.gap
            if closing > 0:
                dt = min(dt, (st.gap - mean) / closing)
        if r.speed > r.spread:
            solid = self.measure(st)[2]
            dt = min(dt, 0.25 * (1.0 - solid) * st.gap / (solid * (r.speed - r.spread)))
        return min(dt, (st.gap - self.gap_end) / r.speed) if r.speed > 0 else dt

    def speed_phase(self, st: _State) -> tuple[_State, _Rates | None]:
        """Speed control until the force limit (returns the state and its rates there) or
        until an incompressible charge fills the cavity (returns the final state and None)."""
        case = self.case
        dt_max = (case.gap0 - self.gap_end) / (case.speed * self.o.closing_steps)
        r = self.rates(st, False)
        while r is not None and r.force < case.force_limit:
            self.record(st, r.force)
            dt = self.step_size(st, r, dt_max)
            new = self.advance(st, r, dt)
            new_r = self.rates(new, False)
            if new_r is None:  # full: the force jumps to the limit
                self.record(new, r.force)
                self.run.switch = new.t + self.o.jump_time_s
                self._hold(new, self.run.switch)
                return new, None
            if new_r.force >= case.force_limit:
                st, r = self._locate_switch(st, r, dt, new_r)
                break
            st, r = new, new_r
        if r is None:
            raise SolverError(f"configuration '{case.id}': the charge fills the cavity at first contact")
        self.run.switch = st.t
        self.record(st, case.force_limit)
        return st, r

    def _locate_switch(self, st: _State, r: _Rates, dt: float, hi: _Rates) -> tuple[_State, _Rates]:
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

    def force_phase(self, st: _State) -> None:
        """Force control from the switch state for the hold time."""
        case, run = self.case, self.run
        t_end = run.switch + case.hold
        dH = max(st.gap - self.gap_end, 0.0) / self.o.hold_steps
        r = self.rates(st, True)
        while r is not None and st.t < t_end:
            dt = min(self.step_size(st, r, np.inf), dH / r.speed if r.speed > 0 else np.inf, t_end - st.t)
            for _ in range(30):  # a creep step must not compact past P_c(s) = F / A
                new = self.advance(st, r, dt)
                new_r = self.rates(new, True)
                if r.sol is not None or new_r is None or new_r.speed > 0 or r.speed <= 0:
                    break
                dt *= 0.5
            st, r = new, new_r
            self.record(st, case.force_limit)
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
    out = {k: np.zeros((P, S)) for k in ("t", "gap", "area", "force", "solid")}
    count = np.zeros(P, dtype=np.int64)
    for i, r in enumerate(runs):
        n = len(r.t)
        count[i] = n
        for key, vals in (("t", r.t), ("gap", r.gap), ("area", r.area), ("force", r.force),
                          ("solid", r.solid)):
            arr = np.asarray(vals, dtype=float)
            out[key][i, :n] = arr
            out[key][i, n:] = arr[-1]
    return Nodes(time=out["t"], gap=out["gap"], area=out["area"], force=out["force"],
                 deflection=np.zeros((P, S)), solid=out["solid"], count=count,
                 switch=np.array([r.switch for r in runs]), status=[r.status for r in runs])
