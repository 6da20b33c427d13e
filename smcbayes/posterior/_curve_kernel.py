"""numba kernel of :meth:`smcbayes.posterior.curves.CurveFeatures.loss` (imported on first
use).

The emulator's samplers evaluate the loss of tens of thousands of emulated curves a
round, most of them in calls of a few rows (the emcee ensembles' half-walkers).  One call
compares every row with every configuration's measured curve, so that a call costs its
arithmetic rather than one dispatch per configuration.  Each row's grid is walked once:
the simulated curve's nodes are evenly spaced, so its bracket is index arithmetic, and the
measured curve's bracket moves forward with the rising grid.  Most rows share each
configuration's usual window (it ends at the measured curve's end, or at its flow stop),
on whose grid the caller interpolates the measured curve once (:func:`measured_on_grid`).
Many rows are shared out in blocks over numba's threads; each row's arithmetic is the
same, so the result does not depend on their number.
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
def _row_mse(force: NDArray[np.float64], switch: float, delay: float, end: float, grid: NDArray[np.float64],
             time_m: NDArray[np.float64], force_m: NDArray[np.float64], common: NDArray[np.float64],
             common_end: float, own: NDArray[np.float64]) -> float:
    """One row's mean squared force error (kN^2) over its window (see :func:`loss_rows`):
    ``force`` ``(n,)`` at nodes evenly spaced over [0, ``switch``], ``common`` ``(G,)`` the
    measured force on the window ending at ``common_end``, ``own`` ``(G,)`` scratch."""
    n = force.shape[0]
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
        err = force[i] * (1.0 - w) + force[i + 1] * w - measured[g]
        total += err * err
    return total / G


@_jit
def _row_loss(features: NDArray[np.float64], p: int, n: int, end_state: bool, flow_stop: bool, bound: float,
              end_stack: NDArray[np.float64], speed: NDArray[np.float64], common_end: NDArray[np.float64],
              common: NDArray[np.float64], grid: NDArray[np.float64], time_m: NDArray[np.float64],
              force_m: NDArray[np.float64], starts: NDArray[np.int64], own: NDArray[np.float64]) -> float:
    """Row ``p``'s sum over the configurations of :func:`_row_mse` (see :func:`loss_rows`)."""
    count = common_end.shape[0]
    total = 0.0
    for k in range(count):
        switch = features[p, count * n + k]
        if switch == switch and not switch > 1e-9:  # numpy.maximum(switch, 1e-9): NaN stays
            switch = 1e-9
        delay = 0.0
        if end_state:
            offset = end_stack[k] - features[p, count * (n + 1) + k]
            if bound > 0.0 and offset == offset:
                offset = min(max(offset, -bound), bound)
            delay = offset / speed[k]
        end = common_end[k]
        if not flow_stop:
            late = switch + delay
            if late != late or late > end:
                end = late
        a, b = starts[k], starts[k + 1]
        total += _row_mse(features[p, k * n:(k + 1) * n], switch, delay, end, grid, time_m[a:b], force_m[a:b],
                          common[k], common_end[k], own)
    return total


@_jit
def loss_rows(features: NDArray[np.float64], n: int, end_state: bool, flow_stop: bool, bound: float,
              end_stack: NDArray[np.float64], speed: NDArray[np.float64], common_end: NDArray[np.float64],
              common: NDArray[np.float64], grid: NDArray[np.float64], time_m: NDArray[np.float64],
              force_m: NDArray[np.float64], starts: NDArray[np.int64], out: NDArray[np.float64]) -> None:
    """Write to ``out`` ``(P,)`` each row's sum over the ``K`` configurations of its mean
    squared force error (kN^2) over the configuration's window.

    Args:
        features: ``(P, K (n + 1 + e))``: each configuration's simulated force (kN) at
            ``n >= 2`` nodes evenly spaced over [0, switch], then the K switch times (s)
            and, with ``end_state`` (e = 1), the K end heights (mm).
        end_state: each configuration's contact is delayed by (``end_stack`` - end height)
            (mm, clipped to +-``bound`` when ``bound > 0``) over ``speed`` (mm/s), both
            ``(K,)``; otherwise the delay is 0.
        flow_stop: every window ends at ``common_end``; otherwise at the later of it and
            the delayed switch.
        common_end: each configuration's usual window end ``(K,)`` (s), at which ``common``
            ``(K, G)`` holds the measured force (:func:`measured_on_grid`).
        grid: the window's points as shares of it ``(G,)``, rising from 0 to 1.
        time_m, force_m: the measured curves, concatenated (s, kN), configuration ``k``'s
            at ``starts[k]:starts[k + 1]`` (``starts`` ``(K + 1,)``), at least 2 points
            each, times rising.
        out: the sums ``(P,)``; a row with a NaN switch time, delay or end gets NaN.

    The simulated curve's first value is held before the delayed contact and its switch
    value beyond the switch; the measured curve's ends are held.
    """
    own = np.empty(grid.shape[0])
    for p in range(features.shape[0]):
        out[p] = _row_loss(features, p, n, end_state, flow_stop, bound, end_stack, speed, common_end, common,
                           grid, time_m, force_m, starts, own)


@_parallel
def loss_rows_parallel(features: NDArray[np.float64], n: int, end_state: bool, flow_stop: bool, bound: float,
                       end_stack: NDArray[np.float64], speed: NDArray[np.float64],
                       common_end: NDArray[np.float64], common: NDArray[np.float64],
                       grid: NDArray[np.float64], time_m: NDArray[np.float64], force_m: NDArray[np.float64],
                       starts: NDArray[np.int64], out: NDArray[np.float64], block: int) -> None:
    """:func:`loss_rows` in blocks of ``block`` rows over numba's threads."""
    rows = features.shape[0]
    for b in prange((rows + block - 1) // block):
        own = np.empty(grid.shape[0])
        for p in range(b * block, min(rows, (b + 1) * block)):
            out[p] = _row_loss(features, p, n, end_state, flow_stop, bound, end_stack, speed, common_end,
                               common, grid, time_m, force_m, starts, own)
