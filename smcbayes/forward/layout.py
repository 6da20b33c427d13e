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
# against the filling progress u = (fill - fill0) / (1 - fill0), one row per initial
# coverage fill0.  Measured with the 2-D solver (48 x 48 cells) by benchmarks/forward_2d.py
# for the thesis's centre charges at the parameters of configs/thesis.toml, as the
# geometric mean over the three closing speeds of each coverage.
_PROGRESS = np.concatenate([np.linspace(0.0, 0.9, 46), 1.0 - np.logspace(-1.0, -3.0, 21)[1:]])
_COVERAGE = np.array([0.6, 0.8])
_RATIO = np.array([
    [0.8876, 0.8898, 0.8916, 0.9012, 0.9069, 0.9106, 0.9136, 0.9160, 0.9177, 0.9232, 0.9276,
     0.9306, 0.9331, 0.9352, 0.9370, 0.9400, 0.9436, 0.9463, 0.9488, 0.9504, 0.9520, 0.9539,
     0.9564, 0.9586, 0.9604, 0.9623, 0.9637, 0.9644, 0.9662, 0.9680, 0.9696, 0.9706, 0.9723,
     0.9733, 0.9737, 1.0085, 1.1377, 1.2946, 1.4279, 1.5657, 1.6731, 1.7911, 1.8994, 1.9979,
     2.0863, 2.1843, 2.2852, 2.3785, 2.4702, 2.5411, 2.6268, 2.6931, 2.7591, 2.8242, 2.8856,
     2.9426, 2.9987, 3.0543, 3.1099, 3.1364, 3.1627, 3.1891, 3.2155, 3.2418, 3.2682, 3.2945],
    [0.8899, 0.8911, 0.8921, 0.8931, 0.8940, 0.8948, 0.8956, 0.8963, 0.9009, 0.9036, 0.9055,
     0.9073, 0.9089, 0.9103, 0.9117, 0.9126, 0.9140, 0.9148, 0.9156, 0.9166, 0.9173, 0.9187,
     0.9210, 0.9227, 0.9246, 0.9259, 0.9272, 0.9283, 0.9295, 0.9303, 0.9314, 0.9321, 0.9332,
     0.9339, 0.9347, 0.9716, 1.1575, 1.3557, 1.5350, 1.7180, 1.8851, 2.0691, 2.2336, 2.3846,
     2.5315, 2.6803, 2.8175, 2.9172, 3.0142, 3.1044, 3.1895, 3.2655, 3.3378, 3.3983, 3.4753,
     3.5428, 3.5940, 3.6430, 3.6885, 3.7341, 3.7487, 3.7536, 3.7585, 3.7635, 3.7684, 3.7733]])


def square_charge_factor(fill: Array, fill0: float) -> Array:
    """Shape correction of the 1-D force for a centred square charge in a square mould.

    The 1-D solver replaces the square by the disc of equal area; that disc never meets
    the mould walls, whereas the square's front reaches the wall centres first and the
    corners fill last, so the 2-D force rises much earlier and more steeply towards the
    end of the filling.  Multiplying the 1-D force by this factor approximates the 2-D
    force.  The table was measured at the thesis's parameters (n = 0.4, tau* = 1e4 Pa,
    B = 1e4 Pa s, tau_c = 0.05 MPa, m = 1.5) and speeds 0.3-1.1 mm/s; it is linear in the
    initial coverage between 60 % and 80 % and held constant outside.

    Args:
        fill: charge area / cavity area (-), any shape.
        fill0: initial charge area / cavity area (-).

    Returns:
        Multiplicative factor on the axisymmetric force (-), same shape as ``fill``.
    """
    fill = np.asarray(fill, dtype=float)
    u = np.clip((fill - fill0) / max(1.0 - fill0, 1e-12), 0.0, 1.0)
    x = -np.log10(np.maximum(1.0 - u, 1e-12))
    rows = [np.interp(x, -np.log10(1.0 - _PROGRESS), r) for r in _RATIO]
    w = float(np.clip((fill0 - _COVERAGE[0]) / (_COVERAGE[1] - _COVERAGE[0]), 0.0, 1.0))
    return np.exp((1.0 - w) * np.log(rows[0]) + w * np.log(rows[1]))


def square_charge_tables(fill0: float) -> tuple[Array, Array, Array, float]:
    """The tables behind :func:`square_charge_factor`, for compiled solvers.

    Returns:
        ``(x, low, high, w)``: progress nodes x = -log10(1 - u) ``(K,)``, the factor rows
        at 60 % and 80 % coverage ``(K,)`` each, and the weight of the 80 % row.
    """
    w = float(np.clip((fill0 - _COVERAGE[0]) / (_COVERAGE[1] - _COVERAGE[0]), 0.0, 1.0))
    return -np.log10(1.0 - _PROGRESS), _RATIO[0].copy(), _RATIO[1].copy(), w
