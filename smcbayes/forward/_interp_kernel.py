"""numba kernels of :func:`smcbayes.forward.nodes.row_weights` and
:func:`~smcbayes.forward.nodes.interp_rows` (imported on first use).

Row-wise linear interpolation: each row's queries are matched to its nodes by a
walk that moves forward while the queries rise (the common case: a time grid), and by
bisection where a query falls back, so a row of ``N`` sorted queries on ``T`` nodes costs
O(N + T) instead of a sort-based search over all rows at once.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit
from numpy.typing import NDArray

# the division is guarded; IEEE semantics as in the marching kernel, no Python checks
_jit = njit(cache=True, error_model="numpy")


@_jit
def _first_above(xp_row: NDArray[np.float64], x: float, lo: int, hi: int) -> int:
    """The first index k in [lo, hi) with ``xp_row[k] > x``, or ``hi`` when none is."""
    while lo < hi:
        mid = (lo + hi) // 2
        if xp_row[mid] > x:
            hi = mid
        else:
            lo = mid + 1
    return lo


@_jit
def _bracket(xp_row: NDArray[np.float64], x: float, j: int, prev: float) -> tuple[int, float, float]:
    """One query ``x`` of a row: its bracket ``j`` and weight, and the clipped query
    (the next call's ``prev``), walking on from the previous query's ``j``."""
    T = xp_row.shape[0]
    if x != x:  # NaN query: NaN value, as numpy.interp gives; the walk goes on from j
        return j, math.nan, prev
    xc = min(max(x, xp_row[0]), xp_row[T - 1])
    if xc < prev:
        j = _first_above(xp_row, xc, 1, T - 1)
    else:
        while j < T - 1 and xp_row[j] <= xc:
            j += 1
    x0, x1 = xp_row[j - 1], xp_row[j]
    return j, ((xc - x0) / (x1 - x0) if x1 > x0 else 1.0), xc


@_jit
def row_weights_kernel(x_new: NDArray[np.float64], xp: NDArray[np.float64],
                       j_out: NDArray[np.int64], w_out: NDArray[np.float64]) -> None:
    """Fill ``j_out`` and ``w_out`` ``(P, N)`` with the brackets and weights of
    :func:`smcbayes.forward.nodes.row_weights` for the queries ``x_new`` ``(P, N)`` on the
    nodes ``xp`` ``(P, T)`` (non-decreasing per row, ``T >= 2``)."""
    P, N = x_new.shape
    for p in range(P):
        j, prev = 1, -math.inf
        for i in range(N):
            j, w, prev = _bracket(xp[p], x_new[p, i], j, prev)
            j_out[p, i] = j
            w_out[p, i] = w


@_jit
def interp_kernel(x_new: NDArray[np.float64], xp: NDArray[np.float64], fp: NDArray[np.float64],
                  out: NDArray[np.float64]) -> None:
    """Fill ``out`` ``(P, N)`` with the values of ``fp`` ``(P, T)`` at ``x_new`` ``(P, N)``
    (:func:`smcbayes.forward.nodes.interp_rows`), without storing the brackets."""
    P, N = x_new.shape
    for p in range(P):
        j, prev = 1, -math.inf
        for i in range(N):
            j, w, prev = _bracket(xp[p], x_new[p, i], j, prev)
            out[p, i] = fp[p, j - 1] + w * (fp[p, j] - fp[p, j - 1])
