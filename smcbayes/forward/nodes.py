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


def interp_rows(x_new: Array, x: Array, y: Array, count: NDArray[np.int64]) -> Array:
    """Row-wise linear interpolation; ``x`` non-decreasing over the first ``count`` entries.

    Args:
        x_new: query points, ``(P, T)``.
        x, y: node abscissae and values, ``(P, S)``.
        count: valid nodes per row, ``(P,)``; entries past it are ignored.

    Returns:
        Interpolated values, ``(P, T)``; constant extrapolation at both ends.
    """
    P, S = x.shape
    idx = np.arange(S)[None, :]
    valid = idx < count[:, None]
    big = np.where(valid, x, np.inf)
    j = np.empty(x_new.shape, dtype=np.int64)
    for r in range(P):  # searchsorted is not batched; this loop is O(P) cheap calls
        j[r] = np.searchsorted(big[r, : count[r]], x_new[r], side="right") - 1
    j = np.clip(j, 0, np.maximum(count - 2, 0)[:, None])
    rows = np.arange(P)[:, None]
    x0, x1 = x[rows, j], x[rows, np.minimum(j + 1, S - 1)]
    y0, y1 = y[rows, j], y[rows, np.minimum(j + 1, S - 1)]
    width = x1 - x0
    with np.errstate(divide="ignore", invalid="ignore"):
        w = np.where(width > 0, (x_new - x0) / width, 1.0)
    return y0 + np.clip(w, 0.0, 1.0) * (y1 - y0)


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
    args = (nodes.time, nodes.count)

    def at(y: Array) -> Array:
        return interp_rows(t, args[0], y, args[1])

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
