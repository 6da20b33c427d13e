"""Pore compaction of a porous charge per cell of the 2-D solver (local solid fraction).

Every cell carries the charge thickness h it holds (pores included; h = H in filled cells)
and the solid volume per unit area sigma = s h, s being the local solid fraction.  The
mixture flows with the Hele-Shaw flux q(grad p) of the base model, the solid is carried
with it at the solid fraction of the upwind cell, and the pores of a cell close at the
volumetric strain rate c (1/s) of the compaction law of
:mod:`smcbayes.forward.effects.compressibility`, applied locally:

    p = P_c(s) + zeta c   while the cell compacts (c > 0),   c = 0 while p <= P_c(s),

so in every filled cell (depth-averaged velocity u = q / H)

    div q = V - H c,            d sigma / dt = -div(s q),           Ds/Dt = s c.

The first is the volume balance of the pressure solve with the monotone sink
H A_cell c(p) (:class:`smcbayes.forward.grid2d.Sink`); the second conserves the solid
exactly in the discrete form (upwind face fluxes, :func:`solid_inflow`); the third follows
from them and is not integrated separately.  Front cells have p = 0 and do not compact,
so material reaches the front at the solid fraction it left its last filled cell with.

The compaction is semi-implicit: over a step dt the law is linearised about the state,
P_c(s (1 + c dt)) ~ P_c(s) + dt s P_c'(s) c, so

    c = (p - P_c(s))^+ / zeta_eff,    zeta_eff = zeta + dt s P_c'(s) > 0.

This is stable for any step and also covers zeta = 0 (rate-independent compaction): the
cell then follows its compaction curve, p -> P_c(s) as dt -> 0, with no regularising
viscosity.  The implicit part dt s P_c'(s) c is the pressure of the end of the step: the
stepper (:mod:`smcbayes.forward.stepper2d`) keeps it below a share of the cell pressure
and leaves it out of the force it records at the start of the step.

With the cavity full there is no front: the whole closing goes into the pores and the
mixture flows only between cells.  Under force control the press keeps closing while some
cell has p > P_c(s) (with zeta = 0 only while the mixture flows from the more compacted
cells to the softer ones) and rests once the uniform pressure F / A exceeds no cell's P_c.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from smcbayes.forward.grid2d import Grid, PressureSolution, Sink

Array = NDArray[np.float64]
Law = Callable[[Array], tuple[Array, Array]]
"""Solid fraction per cell ``(N,)`` -> (P_c (Pa), bulk viscosity zeta (Pa s)), each ``(N,)``."""
CLOSED = 1.0 - 1e-9
"""Solid fraction from which a cell counts as pore-free."""


@dataclass(frozen=True)
class CompactionSink(Sink):
    """:class:`~smcbayes.forward.grid2d.Sink` of the compaction law over one step.

    Attributes:
        stiffness: s P_c'(s) per cell (Pa), ``(nx, ny)``: the implicit part of the
            pressure of a compacting cell is dt * stiffness * c, the step's lag error.
    """

    stiffness: Array


@dataclass(frozen=True)
class CellCompaction:
    """Local pore compaction of one parameter set.

    Attributes:
        solid0: initial solid fraction s0 of the charge (< 1).
        law: the compaction law of the effect (:data:`Law`).
    """

    solid0: float
    law: Law

    def sink(self, solid: Array, full: NDArray[np.bool_], gap: float, dt: float,
             grid: Grid) -> CompactionSink:
        """Compaction sink of the filled cells for a step of ``dt`` (s).

        Args:
            solid: solid fraction per cell, ``(nx, ny)``.
            full: which cells are filled, ``(nx, ny)``.
            gap: current gap H (m).
            dt: step (s) of the semi-implicit compaction.
            grid: the grid.

        Returns:
            Sink with threshold P_c(s) (Pa), coefficient A_cell H / zeta_eff and the
            stiffness s P_c'(s) (Pa).
        """
        s = np.minimum(solid.ravel(), CLOSED)
        pc, zeta = self.law(s)
        ds = 1e-6 * (1.0 - s)  # forward difference: the law has a kink at s0
        pc_up, _ = self.law(s + ds)
        with np.errstate(invalid="ignore"):
            slope = np.where(np.isfinite(pc_up) & np.isfinite(pc), (pc_up - pc) / ds, np.inf)
        zeta_eff = np.asarray(zeta, dtype=float) + dt * s * slope
        ok = (full.ravel() & (solid.ravel() < CLOSED) & np.isfinite(pc) & np.isfinite(zeta_eff)
              & (zeta_eff > 0))
        coeff = np.where(ok, grid.cell_area * gap / np.where(ok, zeta_eff, 1.0), 0.0)
        threshold = np.where(ok, pc, np.inf)
        stiffness = np.where(ok, s * np.where(ok, slope, 0.0), 0.0)
        return CompactionSink(threshold.reshape(solid.shape), coeff.reshape(solid.shape),
                              stiffness.reshape(solid.shape))


def solid_fraction(h: Array, sigma: Array, empty: float) -> Array:
    """Solid fraction per cell ``sigma / h``; ``empty`` where a cell holds nothing."""
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(h > 0.0, sigma / np.where(h > 0.0, h, 1.0), empty)


def solid_inflow(sol: PressureSolution, solid: Array) -> Array:
    """Net solid volume rate into each cell (m^3/s), ``(nx, ny)``.

    Every face carries its volume flux at the solid fraction of its upwind cell, so the
    rates sum to zero over the grid to round-off (walls carry nothing).
    """
    s = solid.ravel()
    out = np.zeros(s.size)
    for fs, q in zip(sol.faces, sol.face_flux, strict=True):
        carried = q * np.where(q >= 0.0, s[fs.a], s[fs.b])
        np.add.at(out, fs.a, -carried)
        np.add.at(out, fs.b, carried)
    return out.reshape(solid.shape)


def largest_outflow(sol: PressureSolution, shape: tuple[int, int]) -> float:
    """Largest total volume rate leaving one cell through its faces (m^3/s)."""
    out = np.zeros(shape[0] * shape[1])
    for fs, q in zip(sol.faces, sol.face_flux, strict=True):
        np.add.at(out, fs.a, np.maximum(q, 0.0))
        np.add.at(out, fs.b, np.maximum(-q, 0.0))
    return float(out.max(initial=0.0))
