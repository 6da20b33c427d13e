"""Solver-independent pieces of a 1-D run: the node record and resampling to outputs.

A solver produces, per parameter set, a sequence of nodes (time, gap, charge area, force,
frame deflection, switch time); this module turns the nodes of all rows into the
:class:`SimulationResult` on each row's output grid (uniform over the closing phase,
geometric over the force-controlled hold).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from smcbayes.forward.case import Case
from smcbayes.forward.result import (
    PHASE_CONTACT,
    PHASE_FLOW,
    PHASE_FORCE,
    PHASE_FULL,
    STATUS_OK,
    SimulationResult,
)
from smcbayes.units import KN, MM

Array = NDArray[np.float64]


@dataclass
class Nodes:
    """Per-row node history; curve arrays have shape ``(P, S)``, padded past each row's end.

    Attributes:
        time, gap, area, force, deflection: SI node values.
        count: number of valid nodes per row, ``(P,)``.
        switch: time force control began (s), ``(P,)``.
        solid: solid fraction at the nodes, ``(P, S)``.
        status: per-row status strings.
    """

    time: Array
    gap: Array
    area: Array
    force: Array
    deflection: Array
    solid: Array
    count: NDArray[np.int64]
    switch: Array
    status: list[str]


def _rows(x_new: Array, xp: Array) -> tuple[Array, Array]:
    """The queries ``(P, N)`` and nodes ``(P, T)`` broadcast to common rows, as the
    compiled kernels want them: C-contiguous, writable float arrays (one compiled version
    for every caller; a broadcast view is read-only and would get its own)."""
    x, nodes = np.atleast_2d(np.asarray(x_new, dtype=float)), np.atleast_2d(np.asarray(xp, dtype=float))
    if x.ndim != 2 or nodes.ndim != 2 or nodes.shape[1] == 0:
        raise ValueError(f"row-wise interpolation takes 2-D queries and nodes (at least one per row), "
                         f"not {x.shape} and {nodes.shape}")
    if nodes.shape[1] == 1:  # a single node: its value everywhere, as numpy.interp gives
        nodes = np.repeat(nodes, 2, axis=1)
    rows = np.broadcast_shapes(x.shape[:1], nodes.shape[:1])
    return (np.require(np.broadcast_to(x, rows + x.shape[1:]), float, ["C", "W"]),
            np.require(np.broadcast_to(nodes, rows + nodes.shape[1:]), float, ["C", "W"]))


def row_weights(x_new: Array, xp: Array) -> tuple[NDArray[np.int64], Array]:
    """Bracketing nodes and weights of row-wise linear interpolation, all rows at once.

    Args:
        x_new: query points, ``(P, N)`` (or rows broadcastable with those of ``xp``).
        xp: node abscissae, non-decreasing per row, ``(P, T)`` (rows may be padded past
            their end by repeating the last node).

    Returns:
        ``(j, w)``, each ``(P, N)``: the value at a query is ``f[j-1] + w (f[j] - f[j-1])``;
        constant extrapolation at both ends, NaN weight at a NaN query, and at a repeated
        node the value of its last copy.  The compiled kernel
        (:mod:`smcbayes.forward._interp_kernel`) walks each row's rising queries along its
        nodes, so a time grid costs O(N + T) per row.

    Raises:
        ValueError: queries or nodes not 2-D, or a row without nodes.
    """
    from smcbayes.forward._interp_kernel import row_weights_kernel  # numba loads on first use

    x, nodes = _rows(x_new, xp)
    j = np.empty(x.shape, dtype=np.int64)
    w = np.empty(x.shape)
    row_weights_kernel(x, nodes, j, w)
    return j, w


def apply_weights(fp: Array, j: NDArray[np.int64], w: Array) -> Array:
    """Values ``(P, N)`` of ``fp`` ``(P, T)`` at the weights of :func:`row_weights`."""
    if fp.shape[1] == 1:  # one node per row (the weights were made on it repeated)
        return np.where(np.isnan(w), np.nan, np.broadcast_to(fp, w.shape))
    rows = np.arange(fp.shape[0])[:, None]
    f0 = fp[rows, j - 1]
    return f0 + w * (fp[rows, j] - f0)


def interp_rows(x_new: Array, xp: Array, fp: Array) -> Array:
    """Row-wise linear interpolation holding end values (``numpy.interp`` per row).

    Args:
        x_new: query points, ``(P, N)`` (or rows broadcastable with those of ``xp``).
        xp: node abscissae, non-decreasing per row, ``(P, T)``.
        fp: node values, ``(P, T)`` (or broadcastable to the rows).

    Returns:
        Values ``(P, N)``; NaN at a NaN query, the last copy's value at a repeated node.
    """
    from smcbayes.forward._interp_kernel import interp_kernel  # numba loads on first use

    x, nodes = _rows(x_new, xp)
    values = np.broadcast_to(fp, (nodes.shape[0], np.shape(xp)[-1]))
    if values.shape[1] == 1:
        values = np.repeat(values, 2, axis=1)
    out = np.empty(x.shape)
    interp_kernel(x, nodes, np.require(values, float, ["C", "W"]), out)
    return out


def output_times(switch: Array, hold: float, closing_points: int, hold_points: int,
                 first_hold_step: float = 0.01) -> Array:
    """Output grid per row: uniform on [0, switch], geometric on (switch, switch + hold].

    Returns:
        Times (s), shape ``(P, closing_points + hold_points)`` (no hold part if hold = 0).
    """
    u = np.linspace(0.0, 1.0, closing_points)
    closing = switch[:, None] * u[None, :]
    if hold <= 0:
        return closing
    first = min(first_hold_step, hold / 10.0)
    d = np.geomspace(first, hold, hold_points)
    return np.concatenate([closing, switch[:, None] + d[None, :]], axis=1)


def to_result(case: Case, nodes: Nodes, closing_points: int, hold_points: int,
              effects: tuple[str, ...]) -> SimulationResult:
    """Resample node histories of all rows onto their output grids."""
    ok = np.array([s == STATUS_OK for s in nodes.status])
    switch = np.where(ok, nodes.switch, 1.0)
    t = output_times(switch, case.hold, closing_points, hold_points)
    # node histories are padded past each row's end with its last node, so one set of
    # weights serves every curve
    weights = row_weights(t, nodes.time)

    def at(y: Array) -> Array:
        return apply_weights(y, *weights)

    force, defl = at(nodes.force), at(nodes.deflection)
    # gap, area and solid fraction are interpolated in log with common weights: their
    # product (solid volume) is constant at the nodes, and so it stays between them
    with np.errstate(divide="ignore"):
        gap, area, solid = (np.exp(at(np.log(v))) for v in (nodes.gap, nodes.area, nodes.solid))
    fill = area / case.area_mould
    phase = np.full(t.shape, PHASE_FLOW, dtype=np.int8)
    phase[fill >= 1.0 - 1e-9] = PHASE_FULL
    phase[t >= switch[:, None] - 1e-12] = PHASE_FORCE
    phase[:, 0] = PHASE_CONTACT
    curves = [t, gap / MM, (case.gap0 - gap + defl) / MM, force / KN, np.minimum(fill, 1.0), solid]
    curves = [np.where(ok[:, None], c, np.nan) for c in curves]
    return SimulationResult(
        config_id=case.id, time_s=curves[0], gap_mm=curves[1], displacement_mm=curves[2],
        force_kN=curves[3], fill_fraction=curves[4], solid_fraction=curves[5], phase=phase,
        switch_time_s=np.where(ok, nodes.switch, np.nan), status=list(nodes.status),
        effects=effects,
    )
