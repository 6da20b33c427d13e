"""numba kernel of :meth:`smcbayes.posterior.curves.CurveFeatures.loss` (imported on first
use).

The emulator's samplers evaluate the loss of tens of thousands of emulated curves a
round; in numpy each configuration's comparison builds several ``(P, G)`` arrays and
searches the measured times of every grid point anew.  Here each row's grid is walked
once: the simulated curve's nodes are evenly spaced, so its bracket is index arithmetic,
and the measured curve's bracket moves forward with the rising grid.  Most rows share one
window (it ends at the measured curve's end, or at its flow stop): the measured curve on
that window's grid is interpolated once per call (:func:`measured_on_grid`).  On one
calibration of the thesis trials (260-960 measured points a trial) the loss of 4,000
emulated rows took 0.075 s instead of 0.126 s (one core, idle).  Many rows are shared out
in blocks over numba's threads; each row's arithmetic is the same, so the result does not
depend on their number.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange
from numpy.typing import NDArray

from smcbayes.forward._interp_kernel import _bracket

# numpy's error model: a division by zero gives inf or NaN, as in the numpy code it replaces.
# The on-disk cache is keyed to this file only: after a change to ``_bracket`` it must be
# cleared (the __pycache__ entries of this module), or the old compiled call stays in use.
_jit = njit(cache=True, error_model="numpy", nogil=True)
_parallel = njit(cache=True, error_model="numpy", parallel=True, nogil=True)


@_jit
def measured_on_grid(end: float, grid: NDArray[np.float64], time_m: NDArray[np.float64],
                     force_m: NDArray[np.float64], out: NDArray[np.float64]) -> None:
    """Write to ``out`` ``(G,)`` the measured force (kN) at the points ``end * grid`` (s) of
    a window ending at ``end``, linearly interpolated in the measured curve."""
    j, prev = 1, -np.inf
    for g in range(grid.shape[0]):
        j, wm, prev = _bracket(time_m, end * grid[g], j, prev)
        out[g] = force_m[j - 1] + wm * (force_m[j] - force_m[j - 1])


@_jit
def _row_mse(force: NDArray[np.float64], p: int, switch: float, delay: float, end: float,
             grid: NDArray[np.float64], time_m: NDArray[np.float64], force_m: NDArray[np.float64],
             common: NDArray[np.float64], common_end: float, own: NDArray[np.float64]) -> float:
    """Row ``p``'s mean squared force error of :func:`force_mse_kernel` (``own`` ``(G,)`` scratch)."""
    n = force.shape[1]
    G = grid.shape[0]
    measured = common
    if end != common_end:
        measured = own
        measured_on_grid(end, grid, time_m, force_m, own)
    total = 0.0
    for g in range(G):
        t = end * grid[g]
        # the first value held before the delayed contact, the switch value beyond the switch
        x = min(max((t - delay) / switch, 0.0), 1.0) * (n - 1)
        if x != x:  # its node index would be undefined
            return np.nan
        i = min(int(np.floor(x)), n - 2)
        w = x - i
        err = force[p, i] * (1.0 - w) + force[p, i + 1] * w - measured[g]
        total += err * err
    return total / G


@_jit
def force_mse_kernel(force: NDArray[np.float64], switch: NDArray[np.float64], delay: NDArray[np.float64],
                     end: NDArray[np.float64], grid: NDArray[np.float64], time_m: NDArray[np.float64],
                     force_m: NDArray[np.float64], out: NDArray[np.float64], common_end: float = np.nan
                     ) -> None:
    """Add to ``out`` ``(P,)`` each row's mean squared force error (kN^2) over its window.

    Args:
        force: simulated force ``(P, n)`` (kN) at ``n >= 2`` nodes evenly spaced over [0, switch].
        switch: switch time per row ``(P,)`` (s, positive).
        delay: delay of the simulated closing per row ``(P,)`` (s).
        end: end of the compared window per row ``(P,)`` (s).
        grid: the window's points as shares of it ``(G,)``, rising from 0 to 1.
        time_m, force_m: the measured curve ``(T >= 2,)`` (s, kN), times rising.
        out: per-row sums to add to ``(P,)``; a row with a NaN switch time, delay or end
            gets NaN.
        common_end: the window's end (s) most rows share, whose measured force is
            interpolated once (:func:`measured_on_grid`); NaN: none.
    """
    common = np.empty(grid.shape[0] if common_end == common_end else 0)
    if common_end == common_end:
        measured_on_grid(common_end, grid, time_m, force_m, common)
    own = np.empty(grid.shape[0])
    for p in range(force.shape[0]):
        out[p] += _row_mse(force, p, switch[p], delay[p], end[p], grid, time_m, force_m, common, common_end,
                           own)


@_parallel
def force_mse_kernel_parallel(force: NDArray[np.float64], switch: NDArray[np.float64],
                              delay: NDArray[np.float64], end: NDArray[np.float64],
                              grid: NDArray[np.float64], time_m: NDArray[np.float64],
                              force_m: NDArray[np.float64], out: NDArray[np.float64], common_end: float,
                              block: int) -> None:
    """:func:`force_mse_kernel` in blocks of ``block`` rows over numba's threads."""
    common = np.empty(grid.shape[0] if common_end == common_end else 0)
    if common_end == common_end:
        measured_on_grid(common_end, grid, time_m, force_m, common)
    rows = force.shape[0]
    for b in prange((rows + block - 1) // block):
        own = np.empty(grid.shape[0])
        for p in range(b * block, min(rows, (b + 1) * block)):
            out[p] += _row_mse(force, p, switch[p], delay[p], end[p], grid, time_m, force_m, common,
                               common_end, own)
