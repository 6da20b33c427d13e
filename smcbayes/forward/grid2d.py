"""Structured finite-volume grid of the mould plane and the nonlinear pressure solve.

Cells are indexed ``(i, j)`` (x along the mould length, y across), shape ``(nx, ny)``.
Only the filled cells (fill fraction 1) carry a pressure unknown; every other cell has
p = 0 (the flow front, as in control-volume filling solvers).  A face between a filled
cell and a front cell places the front at ``(1/2 + f) h`` from the filled cell's centre,
``f`` being the front cell's fill fraction, so the front is located inside its cell
(exact for a straight front).  Mould walls and symmetry planes carry no flux.

Fluxes per unit width follow the generalised Hele-Shaw law q(G) of
:mod:`smcbayes.forward.flux`, written with the fluidity S(G) = q(G) / G:

    sum_faces S_f |face| (p_i - p_nb) / d_f = V A_cell - Q_i      (every filled cell i),

where Q_i = k_i (p_i - P_i)^+ >= 0 is an optional monotone volume sink (pore compaction
of a porous charge, :class:`Sink`; its coefficients come from
:mod:`smcbayes.forward.compaction2d`).

|grad p| at a face combines the normal difference with the mean tangential difference of
the two cells.  The nonlinear system is solved by Newton's method with the exact
Jacobian of this discretisation and step halving (plain Picard on S oscillates once the
local exponent k = d ln q / d ln G of the table exceeds 2, i.e. for strongly
shear-thinning or slip-dominated laws).
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
        plus, minus: flat indices of the tangential neighbours of ``a`` and ``b`` (the cell
            itself at a wall), ``(K, 2)``; the tangential gradient is
            sum(p[plus] - p[minus]) / (2 tangent_step).
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
    plus: NDArray[np.int64]
    minus: NDArray[np.int64]
    tangent_step: float


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
        plus, minus = _tangential(grid, a, b, axis)
        out.append(FaceSet(a, b, fa, fb, dist, length, plus, minus,
                           2.0 * (grid.dy if axis == 0 else grid.dx)))
    return out[0], out[1]


def _tangential(grid: Grid, a: NDArray[np.int64], b: NDArray[np.int64],
                axis: int) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """Tangential neighbours of both cells of each face, clipped at walls: ``(K, 2)`` each."""
    cells = np.stack([a, b], axis=1)
    i, j = np.divmod(cells, grid.ny)
    if axis == 0:
        return i * grid.ny + np.minimum(j + 1, grid.ny - 1), i * grid.ny + np.maximum(j - 1, 0)
    return np.minimum(i + 1, grid.nx - 1) * grid.ny + j, np.maximum(i - 1, 0) * grid.ny + j


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


def _face_gradient(p: Array, fs: FaceSet) -> tuple[Array, Array, Array]:
    """|grad p|, its normal and its tangential part at the faces (Pa/m), each ``(K,)``.

    The tangential part is the mean of the two cells' central differences (one-sided at
    walls and symmetry planes, where the normal gradient vanishes).
    """
    flat = p.ravel()
    gn = (flat[fs.a] - flat[fs.b]) / fs.dist
    gt = (flat[fs.plus] - flat[fs.minus]).sum(axis=1) / (2.0 * fs.tangent_step)
    return np.sqrt(gn * gn + gt * gt), gn, gt


@dataclass(frozen=True)
class Sink:
    """Monotone volume sink of the filled cells: Q = coeff (p - threshold)^+ (m^3/s).

    Attributes:
        threshold: pressure above which the sink acts (Pa), ``(nx, ny)``.
        coeff: volume rate per pascal above it (m^3/(s Pa)), ``(nx, ny)``; 0 where the
            cell has no sink.
    """

    threshold: Array
    coeff: Array

    def rate(self, p: Array) -> tuple[Array, Array]:
        """Sink Q (m^3/s) and dQ/dp (m^3/(s Pa)) per cell at pressure ``p``, each like ``p``."""
        active = (self.coeff > 0) & (p > self.threshold)
        over = np.where(active, p - np.where(active, self.threshold, 0.0), 0.0)
        return self.coeff * over, np.where(active, self.coeff, 0.0)


@dataclass
class PressureSolution:
    """Pressure field and fluxes of one solve.

    Attributes:
        p: pressure per cell (Pa), ``(nx, ny)``, 0 outside the filled region.
        speed: closing speed V (m/s).
        force: press force over the whole mould (N).
        inflow: volume rate into each non-filled cell (m^3/s), ``(nx, ny)``.
        iterations: Newton iterations used.
        sink: volume rate of the sink per cell (m^3/s), ``(nx, ny)`` (zeros without one).
        faces: the x- and y-faces of the solve.
        face_flux: volume rate through each face, from side ``a`` to side ``b`` (m^3/s),
            ``(K_x,)`` and ``(K_y,)``; faces into non-filled cells carry the same scaling
            as ``inflow``, so they sum to it exactly.
    """

    p: Array
    speed: float
    force: float
    inflow: Array
    iterations: int
    sink: Array
    faces: tuple[FaceSet, FaceSet]
    face_flux: tuple[Array, Array]


def _matrix(size: int, unknown: NDArray[np.int64], fx: FaceSet, fy: FaceSet, cx: Array,
            cy: Array) -> sp.csc_matrix:
    """Finite-volume matrix of the filled cells for face conductances ``cx``, ``cy``."""
    rows, cols, vals = [np.arange(size)], [np.arange(size)], []
    diag = np.zeros(size)
    for fs, c in ((fx, cx), (fy, cy)):
        ua, ub = unknown[fs.a], unknown[fs.b]
        np.add.at(diag, ua[fs.full_a], c[fs.full_a])
        np.add.at(diag, ub[fs.full_b], c[fs.full_b])
        both = fs.full_a & fs.full_b
        rows += [ua[both], ub[both]]
        cols += [ub[both], ua[both]]
        vals += [-c[both], -c[both]]
    vals.insert(0, diag)
    return sp.csc_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                         shape=(size, size))


@dataclass
class _Linearised:
    """Face conductances (m^3 s/kg), cell imbalances (m^3/s) and the Jacobian at one iterate."""

    secant: tuple[Array, Array]
    residual: Array
    jacobian: sp.csc_matrix | None


def _linearise(grid: Grid, p: Array, fx: FaceSet, fy: FaceSet, fluidity: Fluidity, speed: float,
               unknown: NDArray[np.int64], jacobian: bool = True, sink: Sink | None = None) -> _Linearised:
    """Volume balance of every filled cell and, if asked, its exact Jacobian.

    The flux through a face is S(G) G_n |face|; its derivative in a cell pressure is
    S |face| [dG_n (1 + (k-1) G_n^2/G^2) + (k-1) G_n G_t / G^2 dG_t], k = d ln q / d ln G.
    """
    size = int((unknown >= 0).sum())
    secant, rows, cols, vals = [], [], [], []
    flux = np.zeros(p.size)
    for fs in (fx, fy):
        G, gn, gt = _face_gradient(p, fs)
        S, k = fluidity(G)
        secant.append(S * fs.length / fs.dist)
        q = S * fs.length * gn
        np.add.at(flux, fs.a, q)
        np.add.at(flux, fs.b, -q)
        if not jacobian:
            continue
        with np.errstate(invalid="ignore", divide="ignore"):
            inv = np.where(G > 0, 1.0 / (G * G), 0.0)
        base = S * fs.length
        dn = base * (1.0 + (k - 1.0) * gn * gn * inv) / fs.dist
        dt = base * (k - 1.0) * gn * gt * inv / (2.0 * fs.tangent_step)
        terms = [(fs.a, dn), (fs.b, -dn)]
        terms += [(fs.plus[:, c], dt) for c in range(2)] + [(fs.minus[:, c], -dt) for c in range(2)]
        for cell, d in terms:
            col = unknown[cell]
            for side, sign in ((fs.a, 1.0), (fs.b, -1.0)):
                row = unknown[side]
                ok = (row >= 0) & (col >= 0)
                rows.append(row[ok])
                cols.append(col[ok])
                vals.append(sign * d[ok])
    where = np.flatnonzero(unknown >= 0)
    residual = flux[where] - speed * grid.cell_area
    if sink is not None:
        q_sink, slope = sink.rate(p)
        residual = residual + q_sink.ravel()[where]
        rows.append(np.arange(size))
        cols.append(np.arange(size))
        vals.append(slope.ravel()[where])
    jac = None
    if jacobian:
        jac = sp.csc_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                            shape=(size, size))
    return _Linearised((secant[0], secant[1]), residual, jac)


def _first_pressure(grid: Grid, full: NDArray[np.bool_], guess: Array | None,
                    faces_: tuple[Array, Array], fluidity: Fluidity, V: float, unknown: NDArray[np.int64],
                    force: float | None, sink: Sink | None, speed_floor: float) -> Array:
    """Start of the Newton iteration of :func:`solve_pressure` (Pa), ``(nx, ny)``.

    The previous solution where there is one; in a full cavity (no front) the candidate
    with the smallest merit among those where some cell compacts; else the solution at
    the zero-stress (Newtonian) fluidity.
    """
    p = np.zeros(full.shape) if guess is None else np.where(full, guess, 0.0)
    if sink is not None and bool(full.all()):
        weight = grid.multiplicity * grid.cell_area
        mean = None if force is None else force / (weight * full.size)
        starts = [pp for pp in [p, *_starts(sink, V * grid.cell_area, mean)] if _acting(pp, sink)]
        if not starts:
            raise SolverError("2-D pressure: the cavity is full and no cell can compact")
        p = min(starts, key=lambda pp: _merit(grid, pp, V, faces_, fluidity, unknown,
                                              force, sink, speed_floor))
    if not np.any(p):
        p.ravel()[np.flatnonzero(full.ravel())] = _cold_start(grid, p, faces_, fluidity, V, unknown, sink)
    return p


def solve_pressure(grid: Grid, fill: Array, fluidity: Fluidity, speed: float | None,
                   force: float | None, guess: Array | None = None, speed_guess: float | None = None,
                   tol: float = 1e-6, max_iter: int = 80, sink: Sink | None = None,
                   speed_floor: float = 0.0) -> PressureSolution:
    """Pressure of the filled region at a given closing speed, or at a given force.

    Newton iteration on the volume balance of the filled cells with step halving.  Under
    force control the speed is a further unknown (bordered system, two solves with one
    factorisation).

    Args:
        grid: the grid.
        fill: fill fraction per cell, ``(nx, ny)``.
        fluidity: the flux law at the current gap.
        speed: closing speed V (m/s) under speed control, else None.
        force: force (N) to hold under force control (``speed`` None).
        guess: pressure field of a previous solve (Pa), ``(nx, ny)``, or None.
        speed_guess: closing speed of a previous solve (m/s), force control only.
        tol: convergence on the largest cell imbalance relative to max(V, speed_floor)
            A_cell (and on the force relative to ``force``).
        max_iter: Newton iteration limit (raises :class:`SolverError` past it).
        sink: volume sink of the filled cells (pore compaction), or None.
        speed_floor: smallest speed (m/s) of the imbalance scale, so that a creeping
            press (V -> 0 under force control) still converges.
    """
    full = fill >= FULL
    fx, fy = faces(grid, full, fill)
    where = np.flatnonzero(full.ravel())
    unknown = np.full(full.size, -1, dtype=np.int64)
    unknown[where] = np.arange(where.size)
    V = speed if speed is not None else (speed_guess or 1e-6)
    problem = _Problem(grid, full, (fx, fy), fluidity, unknown, speed, force, sink, speed_floor, tol,
                       max_iter)
    try:
        p, V, lin, it = _newton(problem, _first_pressure(grid, full, guess, (fx, fy), fluidity, V, unknown,
                                                         force, sink, speed_floor), V)
    except SolverError:
        if guess is None:
            raise
        # a previous solution far from this one (the viscosity of a heating charge can
        # move several-fold over a step) can lead Newton astray; start from zero stress
        p, V, lin, it = _newton(problem, _first_pressure(grid, full, None, (fx, fy), fluidity, V, unknown,
                                                         force, sink, speed_floor), V)
        it += max_iter  # the failed attempt's iterations count too (at most this many)
    q_sink = np.zeros(full.shape) if sink is None else sink.rate(p)[0] * full
    total = V * grid.cell_area * where.size - float(q_sink.sum())
    inflow, face_flux = _inflow(p, fx, fy, lin.secant, full, total)
    weight = grid.multiplicity * grid.cell_area
    return PressureSolution(p=p, speed=V, force=weight * float(p.sum()), inflow=inflow, iterations=it,
                            sink=q_sink, faces=(fx, fy), face_flux=face_flux)


def _acting(p: Array, sink: Sink) -> bool:
    """Whether some sink acts at pressure ``p``."""
    return bool(np.any((sink.coeff > 0) & (p > sink.threshold)))


def _starts(sink: Sink, rate: float, mean: float | None) -> list[Array]:
    """Starting fields (Pa) of a solve without a front (cavity full), sinks active.

    Without a front the Jacobian is singular unless some sink acts.  Under speed control
    the candidates are every sink cell taking ``rate`` (m^3/s) on its own, and the uniform
    pressure at which the sinks take it together (no flow between the cells); under force
    control the uniform mean pressure ``mean`` (Pa).
    """
    if mean is not None:
        return [np.full(sink.coeff.shape, mean)]
    can = sink.coeff > 0
    own = np.where(can, sink.threshold + rate / np.where(can, sink.coeff, 1.0), 0.0)
    total = float(sink.coeff[can].sum())
    if total <= 0.0:
        return [own]
    common = (float((sink.coeff * np.where(can, sink.threshold, 0.0)).sum()) + rate * sink.coeff.size) / total
    return [own, np.full(sink.coeff.shape, common)]


@dataclass(frozen=True)
class _Problem:
    """One pressure solve of :func:`solve_pressure`: its grid, filled cells, faces, flux law,
    unknown numbering, control (``speed`` or ``force``), sink and tolerances."""

    grid: Grid
    full: NDArray[np.bool_]
    faces: tuple[FaceSet, FaceSet]
    fluidity: Fluidity
    unknown: NDArray[np.int64]
    speed: float | None
    force: float | None
    sink: Sink | None
    speed_floor: float
    tol: float
    max_iter: int


def _newton(pb: _Problem, p: Array, V: float) -> tuple[Array, float, _Linearised, int]:
    """Newton iteration of :func:`solve_pressure` from ``p`` (Pa) and ``V`` (m/s); returns
    the pressure, the speed, the last linearisation and the iteration count."""
    grid, (fx, fy) = pb.grid, pb.faces
    weight = grid.multiplicity * grid.cell_area
    closed = pb.sink is not None and bool(pb.full.all())  # no front: some sink must act
    mean = None if pb.force is None else pb.force / (weight * pb.full.size)
    for it in range(1, pb.max_iter + 1):
        lin = _linearise(grid, p, fx, fy, pb.fluidity, V, pb.unknown, sink=pb.sink)
        err = np.max(np.abs(lin.residual), initial=0.0) / (max(V, pb.speed_floor) * grid.cell_area)
        if pb.force is not None:
            err = max(err, abs(weight * float(p.sum()) - pb.force) / pb.force)
        if err < pb.tol:
            return p, V, lin, it
        gap = None if pb.force is None else pb.force / weight - float(p.sum())
        step, dV = _newton_step(lin, grid.cell_area, gap)
        p, V = _line_search(grid, p, V, step, dV, pb.faces, pb.fluidity, pb.unknown, pb.force, pb.sink,
                            pb.speed_floor)
        if closed and not _acting(p, pb.sink):
            p = _starts(pb.sink, V * grid.cell_area, mean)[-1]
    raise SolverError(f"2-D pressure iteration did not converge in {pb.max_iter} iterations "
                      f"(imbalance {err:.2e})")


def _newton_step(lin: _Linearised, cell_area: float, force_gap: float | None) -> tuple[Array, float]:
    """Newton step of the filled cells' pressures (Pa) and of the speed (m/s).

    Under force control (``force_gap``: force / weight - sum p, in Pa) the speed is a
    further unknown: bordered system with d(residual)/dV = -A_cell, solved with the one
    factorisation as step = s0 + dV b and sum(p + step) = force / weight.
    """
    try:
        lu = spla.splu(lin.jacobian)
    except RuntimeError as err:  # no front and no active sink: pressure undetermined
        raise SolverError(f"2-D pressure iteration: singular Jacobian ({err})") from err
    step = -lu.solve(lin.residual)
    if force_gap is None:
        return step, 0.0
    b = lu.solve(np.full(step.size, cell_area))
    dV = (force_gap - float(step.sum())) / float(b.sum())
    return step + dV * b, dV


def _cold_start(grid: Grid, p: Array, fs: tuple[FaceSet, FaceSet], fluidity: Fluidity, V: float,
                unknown: NDArray[np.int64], sink: Sink | None) -> Array:
    """Pressure of the filled cells (Pa) at the zero-stress fluidity, every sink active."""
    where = np.flatnonzero(unknown >= 0)
    lin = _linearise(grid, p, fs[0], fs[1], fluidity, V, unknown, jacobian=False)
    matrix = _matrix(where.size, unknown, fs[0], fs[1], *lin.secant)
    rhs = np.full(where.size, V * grid.cell_area)
    if sink is not None:
        coeff = np.where(np.isfinite(sink.threshold), sink.coeff, 0.0).ravel()[where]
        matrix = matrix + sp.diags(coeff, format="csc")
        rhs = rhs + coeff * np.where(coeff > 0, sink.threshold.ravel()[where], 0.0)
    return spla.spsolve(matrix, rhs)


def _line_search(grid: Grid, p: Array, V: float, step: Array, dV: float, fs: tuple[FaceSet, FaceSet],
                 fluidity: Fluidity, unknown: NDArray[np.int64], force: float | None,
                 sink: Sink | None, speed_floor: float) -> tuple[Array, float]:
    """Newton update, halving the step (at most 12 times) until the merit decreases.

    The merit is the squared cell imbalance relative to max(V, speed_floor) A_cell plus,
    under force control, the squared relative force error: the Newton step of the
    bordered system descends it.
    """
    where = np.flatnonzero(unknown >= 0)
    m0, lam = _merit(grid, p, V, fs, fluidity, unknown, force, sink, speed_floor, V), 1.0
    for _ in range(12):
        trial = p.copy()
        trial.ravel()[where] += lam * step
        V_new = max(V + lam * dV, 1e-3 * V)
        if _merit(grid, trial, V_new, fs, fluidity, unknown, force, sink, speed_floor, V) < m0:
            break
        lam *= 0.5
    return trial, V_new


def _merit(grid: Grid, p: Array, V: float, fs: tuple[FaceSet, FaceSet], fluidity: Fluidity,
           unknown: NDArray[np.int64], force: float | None, sink: Sink | None, speed_floor: float,
           V_scale: float | None = None) -> float:
    """Squared cell imbalance relative to max(V_scale, speed_floor) A_cell (V_scale
    defaults to V) plus, under force control, the squared relative force error."""
    scale = max(V if V_scale is None else V_scale, speed_floor) * grid.cell_area
    r = _linearise(grid, p, fs[0], fs[1], fluidity, V, unknown, jacobian=False, sink=sink).residual
    out = float(np.sum((r / scale) ** 2))
    if force is None:
        return out
    return out + (grid.multiplicity * grid.cell_area * float(p.sum()) / force - 1.0) ** 2


def _inflow(p: Array, fx: FaceSet, fy: FaceSet, cond: tuple[Array, Array], full: Mask,
            total: float) -> tuple[Array, tuple[Array, Array]]:
    """Volume rate into each non-filled cell (m^3/s), scaled to sum to ``total`` exactly,
    and the face fluxes a -> b (m^3/s) with the same scaling on faces into non-filled cells."""
    inflow = np.zeros(p.size)
    flat = p.ravel()
    fluxes = []
    for fs, c in ((fx, cond[0]), (fy, cond[1])):
        q = c * (flat[fs.a] - flat[fs.b])  # volume rate a -> b (m^3/s)
        fluxes.append(q)
        np.add.at(inflow, fs.b[~fs.full_b], q[~fs.full_b])
        np.add.at(inflow, fs.a[~fs.full_a], -q[~fs.full_a])
    got = inflow.sum()
    if got > 0 and total > 0:
        scale = total / got  # removes the solver tolerance from the volume balance
        inflow *= scale
        fluxes = [np.where(fs.full_a & fs.full_b, q, q * scale)
                  for fs, q in zip((fx, fy), fluxes, strict=True)]
    return inflow.reshape(p.shape), (fluxes[0], fluxes[1])
