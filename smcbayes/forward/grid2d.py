"""Structured finite-volume grid of the mould plane and the nonlinear pressure solve.

Cells are indexed ``(i, j)`` (x along the mould length, y across), shape ``(nx, ny)``.
Only the filled cells (fill fraction 1) carry a pressure unknown; every other cell has
p = 0 (the flow front, as in control-volume filling solvers).  A face between a filled
cell and a front cell places the front at ``(1/2 + f) h`` from the filled cell's centre,
``f`` being the front cell's fill fraction, so the front is located inside its cell
(exact for a straight front).  Mould walls and symmetry planes carry no flux.

Fluxes per unit width follow the generalised Hele-Shaw law q(G) of
:mod:`smcbayes.forward.flux`, written with the fluidity S(G) = q(G) / G:

    sum_faces S_f |face| (p_i - p_nb) / d_f = V A_cell      (every filled cell i).

The fluidity is iterated (Picard) with a relaxation 1/k per face, k = d ln q / d ln G the
local power-law exponent of the table: for a power law this is the Newton step of the
one-face problem, which keeps the iteration convergent for strongly shear-thinning and
slip-dominated laws where plain Picard oscillates.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
from numpy.typing import NDArray

from smcbayes.errors import SolverError

Array = NDArray[np.float64]
Mask = NDArray[np.bool_]
FULL = 1.0 - 1e-9
"""Fill fraction from which a cell counts as filled (absorbs round-off)."""


@dataclass(frozen=True)
class Grid:
    """Uniform cells over the solved part of the mould.

    Attributes:
        nx, ny: cells along x and y.
        dx, dy: cell sizes (m).
        x_faces, y_faces: face positions relative to the mould centre (m).
        multiplicity: mould area / solved area (1, 2 or 4 with symmetry planes).
    """

    nx: int
    ny: int
    dx: float
    dy: float
    x_faces: Array
    y_faces: Array
    multiplicity: int

    @property
    def cell_area(self) -> float:
        """Area of one cell (m^2)."""
        return self.dx * self.dy


@dataclass
class FaceSet:
    """The active faces of one direction: cell pairs ``a -> b`` with geometry.

    Attributes:
        a, b: flat cell indices of the two sides, ``(K,)``.
        full_a, full_b: which side is filled, ``(K,)``.
        dist: distance between the pressure points (m), ``(K,)``.
        length: face length (m).
    """

    a: NDArray[np.int64]
    b: NDArray[np.int64]
    full_a: Mask
    full_b: Mask
    dist: Array
    length: float


def faces(grid: Grid, full: Mask, fill: Array) -> tuple[FaceSet, FaceSet]:
    """Faces with at least one filled side, x-faces then y-faces."""
    out = []
    idx = np.arange(grid.nx * grid.ny).reshape(grid.nx, grid.ny)
    for axis, h, length in ((0, grid.dx, grid.dy), (1, grid.dy, grid.dx)):
        lo = [slice(None), slice(None)]
        hi = [slice(None), slice(None)]
        lo[axis], hi[axis] = slice(0, -1), slice(1, None)
        fa, fb = full[tuple(lo)].ravel(), full[tuple(hi)].ravel()
        keep = fa | fb
        a, b = idx[tuple(lo)].ravel()[keep], idx[tuple(hi)].ravel()[keep]
        fa, fb = fa[keep], fb[keep]
        f = fill.ravel()
        # half a cell to the face plus the filled share of the front cell
        dist = np.where(fa & fb, h, np.where(fa, (0.5 + np.minimum(f[b], 1.0)) * h,
                                             (0.5 + np.minimum(f[a], 1.0)) * h))
        out.append(FaceSet(a, b, fa, fb, dist, length))
    return out[0], out[1]


class Fluidity:
    """S(G) = q(G)/G and its local exponent from a flux table at one gap (one row)."""

    def __init__(self, tau: Array, q: Array, gap: float) -> None:
        self.ln_tau0 = float(np.log(tau[0]))
        self.step = float(np.log(tau[1] / tau[0]))
        with np.errstate(divide="ignore"):
            self.ln_q = np.log(np.maximum(q, 1e-300))
        self.slope = np.diff(self.ln_q) / self.step
        self.gap = gap
        self.size = tau.size

    def __call__(self, G: Array) -> tuple[Array, Array]:
        """Fluidity (m^3 s/kg, i.e. (m^2/s)/(Pa/m)) and exponent k = dln q/dln G at G (Pa/m)."""
        ln_g0 = self.ln_tau0 + np.log(2.0 / self.gap)
        ln_g = np.log(np.maximum(G, 1e-300))
        ln_g = np.maximum(ln_g, ln_g0)  # below the table the law is Newtonian: S constant
        x = (ln_g - ln_g0) / self.step
        j = np.clip(np.floor(x).astype(np.int64), 0, self.size - 2)
        k = self.slope[j]
        ln_q = self.ln_q[j] + (x - j) * self.step * k
        return np.exp(ln_q - ln_g), k


def _face_gradient(grid: Grid, p: Array, fs: FaceSet, axis: int) -> Array:
    """|grad p| at faces (Pa/m): normal difference plus the averaged tangential one."""
    flat = p.ravel()
    gn = (flat[fs.a] - flat[fs.b]) / fs.dist
    pad = np.pad(p, 1, mode="edge")  # walls and symmetry planes: zero normal gradient
    if axis == 0:
        gt = (pad[1:-1, 2:] - pad[1:-1, :-2]) / (2.0 * grid.dy)
    else:
        gt = (pad[2:, 1:-1] - pad[:-2, 1:-1]) / (2.0 * grid.dx)
    gt = gt.ravel()
    g_t = 0.5 * (gt[fs.a] + gt[fs.b])
    return np.sqrt(gn * gn + g_t * g_t)


@dataclass
class PressureSolution:
    """Pressure field, face conductances and fluxes of one solve.

    Attributes:
        p: pressure per cell (Pa), ``(nx, ny)``, 0 outside the filled region.
        speed: closing speed V (m/s).
        force: press force over the whole mould (N).
        inflow: volume rate into each non-filled cell (m^3/s), ``(nx, ny)``.
        fluidity: final face fluidities (x-faces, y-faces), kept to warm-start the next solve.
        iterations: Picard iterations used.
    """

    p: Array
    speed: float
    force: float
    inflow: Array
    fluidity: tuple[Array, Array]
    iterations: int


def _linear_solve(grid: Grid, full: Mask, fx: FaceSet, fy: FaceSet, cx: Array, cy: Array) -> Array:
    """Pressure for a unit closing speed with face conductances ``cx``, ``cy`` (m^3 s/kg)."""
    n = grid.nx * grid.ny
    where = np.flatnonzero(full.ravel())
    unknown = np.full(n, -1, dtype=np.int64)
    unknown[where] = np.arange(where.size)
    rows, cols, vals = [], [], []
    diag = np.zeros(where.size)
    for fs, c in ((fx, cx), (fy, cy)):
        ua, ub = unknown[fs.a], unknown[fs.b]
        np.add.at(diag, ua[fs.full_a], c[fs.full_a])
        np.add.at(diag, ub[fs.full_b], c[fs.full_b])
        both = fs.full_a & fs.full_b
        rows += [ua[both], ub[both]]
        cols += [ub[both], ua[both]]
        vals += [-c[both], -c[both]]
    rows.append(np.arange(where.size))
    cols.append(np.arange(where.size))
    vals.append(diag)
    A = sp.csc_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                      shape=(where.size, where.size))
    rhs = np.full(where.size, grid.cell_area)
    p = np.zeros(n)
    p[where] = spla.spsolve(A, rhs)
    return p.reshape(grid.nx, grid.ny)


def solve_pressure(grid: Grid, fill: Array, fluidity: Fluidity, speed: float | None,
                   force: float | None, guess: tuple[Array, Array] | None = None,
                   tol: float = 1e-7, max_iter: int = 200) -> PressureSolution:
    """Pressure of the filled region at a given closing speed, or at a given force.

    Args:
        grid: the grid.
        fill: fill fraction per cell, ``(nx, ny)``.
        fluidity: the flux law at the current gap.
        speed: closing speed V (m/s) under speed control, else None.
        force: force (N) to hold under force control (``speed`` None).
        guess: face fluidities (x, y) of a previous solve on the same grid, or None.
        tol: convergence on max |ln S(G) - ln S| over the faces.
        max_iter: Picard iteration limit (raises :class:`SolverError` past it).
    """
    full = fill >= FULL
    fx, fy = faces(grid, full, fill)
    size = grid.nx * grid.ny
    if guess is None:
        s0 = fluidity(np.array([1e-3]))[0][0]
        sx, sy = np.full(size, s0), np.full(size, s0)
    else:
        sx, sy = guess[0].copy(), guess[1].copy()
    for it in range(1, max_iter + 1):
        cx, cy = sx[fx.a] * fx.length / fx.dist, sy[fy.a] * fy.length / fy.dist
        p1 = _linear_solve(grid, full, fx, fy, cx, cy)
        F1 = grid.multiplicity * grid.cell_area * float(p1.sum())
        V = speed if speed is not None else force / F1
        p = V * p1
        worst = 0.0
        for fs, s, axis in ((fx, sx, 0), (fy, sy, 1)):
            target, k = fluidity(_face_gradient(grid, p, fs, axis))
            delta = np.log(target) - np.log(s[fs.a])
            worst = max(worst, float(np.max(np.abs(delta), initial=0.0)))
            s[fs.a] = s[fs.a] * np.exp(delta / np.maximum(k, 1.0))
        if worst < tol:
            break
    else:
        raise SolverError(f"2-D pressure iteration did not converge in {max_iter} iterations "
                          f"(last fluidity change {worst:.2e})")
    inflow = np.zeros(size)
    for fs, c in ((fx, cx), (fy, cy)):
        q = V * c * (p1.ravel()[fs.a] - p1.ravel()[fs.b])  # volume rate a -> b (m^3/s)
        np.add.at(inflow, fs.b[~fs.full_b], q[~fs.full_b])
        np.add.at(inflow, fs.a[~fs.full_a], -q[~fs.full_a])
    return PressureSolution(p=p, speed=V, force=V * F1, inflow=inflow.reshape(grid.nx, grid.ny),
                            fluidity=(sx, sy), iterations=it)
