"""numba kernels of :func:`smcbayes.posterior.curves.matern52` (imported on first use).

The curve emulator evaluates its correlation at every point its samplers visit (rows
against the training points) and, in each likelihood evaluation of its fit, between all
training points.  In numpy the squared distances come from one matrix product, but the
square root, the exponential and the polynomial each pass over an ``(N, M)`` temporary.
Here each row's squared distances are summed over the coordinates with the points on the
innermost, contiguous axis (so the compiler vectorises over them) and turned into the
correlation in one pass; the correlation of a set of points with itself is computed on one
triangle and mirrored.  The distances are summed from the coordinate differences, which
stay accurate where the matrix-product form cancels: at two near-identical points that
form leaves a rounding error of order machine epsilon times the squared scaled norm.
Many rows at once (:data:`smcbayes.posterior._blocks.PARALLEL_ROWS`) are shared out in
blocks over numba's threads (:func:`matern52_rows_parallel`); each row's arithmetic is the
same, so the result does not depend on the number of threads.  The fit's gradient in the
log lengthscales (:func:`matern52_lengthscale_gradient`) sums a weight matrix times the
correlation's derivatives over one triangle of the pairs, without forming the ``d``
derivative matrices.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange
from numpy.typing import NDArray

# numpy's error model; no fast-math, so that the compiler keeps the order of the
# arithmetic (the exponential is still the platform's)
_jit = njit(cache=True, error_model="numpy", nogil=True)
_parallel = njit(cache=True, error_model="numpy", parallel=True, nogil=True)


@_jit
def _row(sa: NDArray[np.float64], i: int, sbt: NDArray[np.float64], r2: NDArray[np.float64],
         out: NDArray[np.float64]) -> None:
    """Row ``i`` of :func:`matern52_rows` (``r2`` ``(M,)`` scratch)."""
    d, m = sbt.shape
    r2[:] = 0.0
    for k in range(d):
        a = sa[i, k]
        for j in range(m):
            t = a - sbt[k, j]
            r2[j] += t * t
    for j in range(m):
        s = math.sqrt(5.0 * r2[j])
        out[i, j] = (1.0 + s + s * s / 3.0) * math.exp(-s)


@_jit
def matern52_rows(sa: NDArray[np.float64], sbt: NDArray[np.float64], out: NDArray[np.float64]) -> None:
    """Write to ``out`` ``(N, M)`` the Matern-5/2 correlation of the scaled points ``sa``
    ``(N, d)`` with the scaled points given transposed, ``sbt`` ``(d, M)`` (coordinates
    divided by the lengthscales)."""
    r2 = np.empty(sbt.shape[1])
    for i in range(sa.shape[0]):
        _row(sa, i, sbt, r2, out)


@_parallel
def matern52_rows_parallel(sa: NDArray[np.float64], sbt: NDArray[np.float64], out: NDArray[np.float64],
                           block: int) -> None:
    """:func:`matern52_rows` in blocks of ``block`` rows over numba's threads."""
    n = sa.shape[0]
    for b in prange((n + block - 1) // block):
        r2 = np.empty(sbt.shape[1])
        for i in range(b * block, min(n, (b + 1) * block)):
            _row(sa, i, sbt, r2, out)


@_jit
def matern52_self(sa: NDArray[np.float64], sat: NDArray[np.float64], out: NDArray[np.float64]) -> None:
    """Write to ``out`` ``(N, N)`` the Matern-5/2 correlation of the scaled points ``sa``
    ``(N, d)`` with themselves (``sat`` the same points transposed, ``(d, N)``): the lower
    triangle computed, the upper one mirrored, so that ``out`` is exactly symmetric."""
    n, d = sa.shape
    r2 = np.empty(n)
    for i in range(n):
        r2[:i + 1] = 0.0
        for k in range(d):
            a = sa[i, k]
            for j in range(i + 1):
                t = a - sat[k, j]
                r2[j] += t * t
        for j in range(i + 1):
            s = math.sqrt(5.0 * r2[j])
            value = (1.0 + s + s * s / 3.0) * math.exp(-s)
            out[i, j] = value
            out[j, i] = value


@_jit
def matern52_lengthscale_gradient(sa: NDArray[np.float64], sat: NDArray[np.float64], w: NDArray[np.float64],
                                  out: NDArray[np.float64]) -> None:
    """Write to ``out`` ``(d,)`` the sums over the pairs ``i < j`` of ``w[i, j]`` times the
    derivative of the Matern-5/2 correlation of the scaled points ``sa`` ``(N, d)`` (``sat``
    the same points transposed, ``(d, N)``) with respect to each log lengthscale: only the
    upper triangle of ``w`` ``(N, N)`` is read, row by row.

    With ``s = sqrt(5) r``, the correlation ``(1 + s + s^2 / 3) exp(-s)`` has derivative
    ``(5 / 3) (1 + s) exp(-s) t_k^2`` in the log lengthscale ``k``, where ``t_k`` is the
    pair's scaled difference in coordinate ``k``."""
    n, d = sa.shape
    g = np.empty(n)
    t2 = np.empty((d, n))
    out[:] = 0.0
    for i in range(n - 1):
        g[i + 1:] = 0.0
        for k in range(d):
            a = sa[i, k]
            for j in range(i + 1, n):
                t = a - sat[k, j]
                t2[k, j] = t * t
                g[j] += t * t
        for j in range(i + 1, n):
            s = math.sqrt(5.0 * g[j])
            g[j] = w[i, j] * (5.0 / 3.0) * (1.0 + s) * math.exp(-s)
        for k in range(d):
            acc = 0.0
            for j in range(i + 1, n):
                acc += g[j] * t2[k, j]
            out[k] += acc
