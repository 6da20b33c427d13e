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
    """Pass the content above ``gap`` on to neighbours until no cell overflows (m).

    Excess goes in equal shares to the non-filled neighbours, or to all neighbours when a
    cell has none (they pass it on).  The total is conserved exactly.
    """
    h = h.copy()
    for _ in range(10 * sum(h.shape)):
        excess = np.maximum(h - gap, 0.0)
        if excess.max() <= 1e-14 * gap:
            return h
        h -= excess
        open_ = np.pad(h < gap * FULL, 1, constant_values=False)
        exists = np.pad(np.ones(h.shape, bool), 1, constant_values=False)
        shifts = ((0, 1), (2, 1), (1, 0), (1, 2))
        targets = [open_[a:a + h.shape[0], b:b + h.shape[1]] for a, b in shifts]
        count = sum(t.astype(float) for t in targets)
        if np.any((count == 0) & (excess > 0)):
            targets = [exists[a:a + h.shape[0], b:b + h.shape[1]] for a, b in shifts]
            count = np.where(count == 0, sum(t.astype(float) for t in targets), count)
            targets = [np.where(count > 0, t, False) for t in targets]
        share = excess / np.maximum(count, 1.0)
        padded = np.zeros((h.shape[0] + 2, h.shape[1] + 2))
        for (a, b), t in zip(shifts, targets):
            # a neighbour at offset (a-1, b-1) receives from the cell at the opposite side
            padded[2 - a:2 - a + h.shape[0], 2 - b:2 - b + h.shape[1]] += np.where(t, share, 0.0)
        h += padded[1:-1, 1:-1]
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
