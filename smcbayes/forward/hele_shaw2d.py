"""2-D thin-cavity reference solver (``hele_shaw2d``) for arbitrary charge layouts.

Generalised Hele-Shaw flow with wall slip on the mould plane (design 4.2), solved by
finite volumes on a structured grid with a fill-fraction (control-volume) flow front:

* every cell carries the charge thickness h = f H it holds (f the fill fraction);
* filled cells (f = 1) carry the pressure, div(S(|grad p|) grad p) = -V, front cells have
  p = 0 and mould walls no flux (:mod:`smcbayes.forward.grid2d`);
* front cells gain the volume flowing in from filled cells, filled cells lose V per unit
  area; a cell whose content exceeds the gap passes the excess on to its neighbours, so
  the charge volume is conserved to round-off;
* the press protocol is the 1-D solver's (:mod:`smcbayes.forward.stepper2d`): speed
  control at the ram's speed (the set speed or a measured profile's, ramped and slowed by
  the force with ``speed_ramp``) until the force limit (located inside a step by regula
  falsi in the step size), then force control (the closing speed that gives F = F_limit, solved
  together with the pressure) for the hold time; an incompressible charge that fills the
  cavity stops the gap and the force jumps to the limit.  A compliant frame
  (``press_compliance``) deflects by F / k, so the gap closes slower than the ram while the
  force rises (balanced at the end of each step, as in the 1-D solver), and once the cavity
  is full the ram runs on and loads it to the limit.

Mirror symmetry of the layout about the mould's centre lines is used to solve a half or a
quarter of the mould.  Parameter sets are solved one after another.

The base model, measured ram profiles and every built-in effect (``compressibility``,
``heating``, ``curing``, ``speed_ramp``, ``press_compliance``) are supported.  A porous
charge has a local solid fraction per cell (:mod:`smcbayes.forward.compaction2d`): each
filled cell compacts under its own pressure by the effect's law, the solid moves with the
flow, and the solid volume is conserved to round-off.  Heating and curing act on the whole
charge as in the 1-D solver: one mean temperature and degree of cure per parameter set,
advanced over each step at its start gap, scale the viscosity of every cell
(:class:`~smcbayes.forward.law2d.ChargeEffects`); with ``speed_ramp`` the closing
speed of each step under speed control is the ram's, slowed by the step's force.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np
from numpy.typing import NDArray

from smcbayes.config import MaterialSpec, SolverSpec
from smcbayes.errors import ConfigError, SolverError
from smcbayes.forward.case import Case
from smcbayes.forward.compaction2d import CellCompaction
from smcbayes.forward.effects.base import EffectStack
from smcbayes.forward.flux import MaterialTable, log_grid
from smcbayes.forward.grid2d import Grid
from smcbayes.forward.law2d import ChargeEffects, Law
from smcbayes.forward.layout import coverage, symmetric
from smcbayes.forward.nodes import Nodes, to_result
from smcbayes.forward.result import SimulationResult
from smcbayes.forward.spill2d import spill
from smcbayes.forward.squeeze1d import material_table
from smcbayes.forward.stepper2d import HeleShaw2DOptions, Run, Stepper

__all__ = ["FillHistory", "HeleShaw2D", "HeleShaw2DOptions", "cell_compaction", "charge_effects", "make_grid",
           "spill", "whole_mould"]

Array = NDArray[np.float64]
SUPPORTED_EFFECTS = ("compressibility", "heating", "curing", "speed_ramp", "press_compliance")


@dataclass
class FillHistory:
    """Fill-fraction fields of one run over the whole mould.

    Attributes:
        time_s: snapshot times (s), ``(K,)``.
        fill: fill fraction per cell, ``(K, NX, NY)`` (NX along the mould length).
        x_faces_mm, y_faces_mm: cell faces of the whole mould relative to its centre (mm).
        solid: solid fraction per cell, ``(K, NX, NY)`` (NaN in empty cells), or None for
            an incompressible charge.
    """

    time_s: Array
    fill: Array
    x_faces_mm: Array
    y_faces_mm: Array
    solid: Array | None = None


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
            effects: the enabled effects: any of ``compressibility`` (pore compaction
                with a local solid fraction per cell), ``heating`` and ``curing`` (one
                charge-mean state per row), ``speed_ramp`` and ``press_compliance``.
            material: slip coefficient and threshold exponent.
        """
        other = [n for n in effects.names if n not in SUPPORTED_EFFECTS]
        if other:
            raise ConfigError(f"the 2-D solver supports the effects {', '.join(SUPPORTED_EFFECTS)} only; "
                              f"switch off {', '.join(other)} or use --fidelity 1d")
        table = material_table(p, material, self.tau)
        rows = p["n"].shape[0]
        runs = []
        for r in range(rows):
            # one parameter set that fails must not take the other rows of the batch with it
            try:
                row_effects = cell_compaction(case, p, effects, r), charge_effects(case, p, effects, r)
                runs.append(self.run_row(case, table, float(p["B"][r]), r, *row_effects))
            except SolverError as err:
                runs.append(Run(t=[0.0, 1.0], gap=[case.gap0] * 2, area=[case.area0] * 2,
                                force=[0.0, 0.0], deflection=[0.0, 0.0], solid=[1.0, 1.0], switch=1.0,
                                status=f"failed: {err}"))
        grid, _ = make_grid(case, self.options.cells, self.options.use_symmetry)
        porous = effects.solid_fraction0(case, p, rows) is not None
        self.fields[case.id] = [self._history(grid, run, porous) if run.snap_f else None for run in runs]
        nodes = _to_nodes(runs)
        o = self.options
        return to_result(case, nodes, o.output_closing_points, o.output_hold_points,
                         tuple(effects.names))

    def _history(self, grid: Grid, run: Run, porous: bool) -> FillHistory:
        fills = [whole_mould(grid, f)[0] for f in run.snap_f]
        solid = np.array([whole_mould(grid, s)[0] for s in run.snap_s]) if porous else None
        _, xf, yf = whole_mould(grid, run.snap_f[0])
        return FillHistory(np.array(run.snap_t), np.array(fills), xf * 1e3, yf * 1e3, solid)

    def run_row(self, case: Case, table: MaterialTable, eta0: float, row: int,
                compaction: CellCompaction | None = None, charge: ChargeEffects | None = None) -> Run:
        """Simulate one parameter set (row ``row`` of ``table``); returns its node record.

        Args:
            case: the configuration in SI.
            table: flux tables of the batch.
            eta0: zero-shear viscosity of the row (Pa s).
            row: row of ``table``.
            compaction: per-cell pore compaction, or None for an incompressible charge.
            charge: the row's effects on the whole charge and the press, or None.
        """
        o = self.options
        grid, h0 = make_grid(case, o.cells, o.use_symmetry)
        law = Law(self.tau, table.slip[row], table.shear[row] / (2.0 * eta0 * self.tau**2),
                  table.take(np.array([row])), eta0)
        stepper = Stepper(case, grid, law, o, compaction, charge)
        state, rates = stepper.speed_phase(stepper.initial(h0))
        if rates is not None:
            stepper.force_phase(state)
        return stepper.run


def charge_effects(case: Case, p: dict[str, Array], effects: EffectStack, row: int) -> ChargeEffects | None:
    """The effects of row ``row`` on the whole charge and the press, or None when no enabled
    effect carries a state, moves the ram or deflects the frame (no ``heating``,
    ``curing``, ``speed_ramp`` or ``press_compliance``)."""
    p_row = {k: np.asarray(v)[row:row + 1] for k, v in p.items()}
    press = {"speed_ramp", "press_compliance"} & set(effects.names)
    if not press and not effects.initial_state(case, p_row, 1):
        return None
    return ChargeEffects(case, p_row, effects)


def cell_compaction(case: Case, p: dict[str, Array], effects: EffectStack, row: int) -> CellCompaction | None:
    """Per-cell compaction of row ``row`` from the effects' hooks, or None (no pores)."""
    s0 = effects.solid_fraction0(case, p, p["n"].shape[0])
    if s0 is None or float(np.asarray(s0)[row]) >= 1.0:
        return None
    p_row = {k: np.asarray(v)[row:row + 1] for k, v in p.items()}

    def law(solid: Array) -> tuple[Array, Array]:
        pc, zeta = effects.compaction(case, p_row, solid)
        return (np.broadcast_to(np.asarray(pc, dtype=float), solid.shape),
                np.broadcast_to(np.asarray(zeta, dtype=float), solid.shape))

    return CellCompaction(float(np.asarray(s0)[row]), law)


def _to_nodes(runs: list[Run]) -> Nodes:
    """Stack the node records of all rows, padding each past its end."""
    P, S = len(runs), max(len(r.t) for r in runs)
    out = {k: np.zeros((P, S)) for k in ("t", "gap", "area", "force", "deflection", "solid")}
    count = np.zeros(P, dtype=np.int64)
    for i, r in enumerate(runs):
        n = len(r.t)
        count[i] = n
        for key, vals in (("t", r.t), ("gap", r.gap), ("area", r.area), ("force", r.force),
                          ("deflection", r.deflection), ("solid", r.solid)):
            arr = np.asarray(vals, dtype=float)
            out[key][i, :n] = arr
            out[key][i, n:] = arr[-1]
    return Nodes(time=out["t"], gap=out["gap"], area=out["area"], force=out["force"],
                 deflection=out["deflection"], solid=out["solid"], count=count,
                 switch=np.array([r.switch for r in runs]), status=[r.status for r in runs])
