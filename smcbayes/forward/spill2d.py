"""Fill update of the 2-D solver: content above the gap spills on to open cells."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray
from scipy import ndimage

from smcbayes.errors import SolverError
from smcbayes.forward.grid2d import FULL

Array = NDArray[np.float64]
Mask = NDArray[np.bool_]


def spill(h: Array, gap: float) -> Array:
    """Pass the content above ``gap`` on to the nearest non-filled cells (m).

    Excess moves one cell per pass down the taxicab distance to the nearest open cell
    (equal shares between the neighbours one step closer), so it reaches the front in as
    many passes as it is cells away.  The total is conserved exactly.
    """
    return spill_with(h, gap, None)[0]


def spill_with(h: Array, gap: float, tracer: Array | None,
               absorb: bool = False) -> tuple[Array, Array | None]:
    """:func:`spill` that moves a tracer per unit area with the excess content.

    Each pass moves the excess at the tracer-to-content ratio of the cell it leaves, so
    the cells it passes through mix with it (well mixed).

    Args:
        h: content per cell (m), ``(nx, ny)``.
        gap: capacity of a cell (m).
        tracer: amount per unit area carried in proportion to the content (e.g. the solid
            volume per unit area, m), ``(nx, ny)``, or None.
        absorb: a full cavity absorbs any excess of ``h`` (a porous charge compacts by it;
            the tracer stays), instead of raising :class:`SolverError` past round-off.

    Returns:
        ``(h, tracer)`` after the redistribution; both totals are conserved exactly (the
        tracer also when the cavity is full and the excess of ``h`` is dropped).
    """
    h = h.copy()
    tracer = None if tracer is None else tracer.copy()
    nx, ny = h.shape
    shifts = ((0, 1), (2, 1), (1, 0), (1, 2))  # neighbour (i + a - 1, j + b - 1)
    for _ in range(4 * (nx + ny) + 10):
        excess = np.where(h > gap * (1.0 + 1e-11), h - gap, 0.0)
        if not excess.any():  # round-off of filled cells stays in place
            return h, tracer
        open_ = h < gap * FULL
        if not open_.any():
            if absorb or excess.sum() <= 1e-9 * h.sum():
                return h - excess, tracer  # cavity full: what is left over is round-off
            raise SolverError("2-D fill update: the charge holds more volume than the cavity")
        dist = ndimage.distance_transform_cdt(~open_, metric="taxicab").astype(float)
        pad = np.pad(dist, 1, constant_values=np.inf)
        targets = [pad[a:a + nx, b:b + ny] == dist - 1.0 for a, b in shifts]
        count = sum(t.astype(float) for t in targets)
        if tracer is not None:
            moved = excess * tracer / np.maximum(h, 1e-300)  # at the source cell's ratio
            tracer += _pass_on(moved, targets, count, shifts) - moved
        h += _pass_on(excess, targets, count, shifts) - excess
    raise SolverError("2-D fill update: overflow could not be redistributed")


def _pass_on(amount: Array, targets: list[Mask], count: Array,
             shifts: tuple[tuple[int, int], ...]) -> Array:
    """What each cell gains when every cell shares ``amount`` among its ``targets``."""
    nx, ny = amount.shape
    share = amount / np.maximum(count, 1.0)
    gained = np.zeros((nx + 2, ny + 2))
    for (a, b), t in zip(shifts, targets, strict=False):
        gained[a:a + nx, b:b + ny] += np.where(t, share, 0.0)
    return gained[1:-1, 1:-1]
