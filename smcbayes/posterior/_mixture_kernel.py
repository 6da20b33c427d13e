"""numba kernels of the expectation-maximisation steps of
:func:`smcbayes.posterior.mixture.fit_mixture` (imported on first use).

Every importance sample of the stage refits its proposal's Gaussian mixture at each
iteration, up to 60 EM steps on a few thousand points each.  In numpy a step builds
``(K, N, d)`` arrays of offsets and whitened offsets, a log-sum-exp and a stacked product
for the scatter matrices, and the fits cost more than the emulator evaluations of the
active learning's rounds.  Here each point is whitened against all components at once with
the components on the innermost, contiguous axis (so the compiler vectorises over them),
using the lower-triangular inverse Cholesky factors, and the scatter matrices are
accumulated in one pass over the points.  One thread: the points are few, and the result
must not depend on the threads.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit
from numpy.typing import NDArray

# numpy's error model, as in the numpy code it replaces; no fast-math: the same result
# on every machine
_jit = njit(cache=True, error_model="numpy", nogil=True)


@_jit
def e_step(x: NDArray[np.float64], w: NDArray[np.float64], mean_t: NDArray[np.float64],
           inv: NDArray[np.float64], const: NDArray[np.float64], resp: NDArray[np.float64]) -> float:
    """The expectation step: write the weighted responsibilities ``w_i r_ik`` to ``resp``
    ``(N, K)`` and return the weighted mean log density ``sum_i w_i log sum_k alpha_k
    N(x_i; mu_k, S_k)``.

    Args:
        x: points ``(N, d)``.
        w: their normalised weights ``(N,)``.
        mean_t: the components' means, transposed ``(d, K)``.
        inv: the inverse lower Cholesky factors of their covariances, ``(d, d, K)``
            (``inv[a, b, k] = L_k^-1[a, b]``; zero above the diagonal, which is skipped).
        const: ``log alpha_k - log det L_k - d/2 log(2 pi)`` ``(K,)``.
        resp: output ``(N, K)``.
    """
    n, d = x.shape
    k_count = mean_t.shape[1]
    diff = np.empty((d, k_count))
    z = np.empty(k_count)
    joint = np.empty(k_count)
    total = 0.0
    for i in range(n):
        for b in range(d):
            for k in range(k_count):
                diff[b, k] = x[i, b] - mean_t[b, k]
        joint[:] = 0.0  # the squared Mahalanobis distances first
        for a in range(d):
            z[:] = 0.0
            for b in range(a + 1):
                for k in range(k_count):
                    z[k] += inv[a, b, k] * diff[b, k]
            for k in range(k_count):
                joint[k] += z[k] * z[k]
        top = -math.inf
        for k in range(k_count):
            joint[k] = const[k] - 0.5 * joint[k]
            top = max(top, joint[k])
        if not math.isfinite(top):  # no component reaches the point: it takes no part
            resp[i, :] = 0.0
            total += w[i] * top
            continue
        norm = 0.0
        for k in range(k_count):
            joint[k] = math.exp(joint[k] - top)
            norm += joint[k]
        total += w[i] * (top + math.log(norm))
        share = w[i] / norm
        for k in range(k_count):
            resp[i, k] = joint[k] * share
    return total


@_jit
def scatter(x: NDArray[np.float64], resp: NDArray[np.float64], mean_t: NDArray[np.float64],
            out: NDArray[np.float64]) -> None:
    """Write to ``out`` ``(d, d, K)`` the scatter matrices ``sum_i resp_ik (x_i - mu_k)
    (x_i - mu_k)^T`` of the points ``x`` ``(N, d)`` about the means ``mean_t`` (transposed,
    ``(d, K)``), with the weighted responsibilities ``resp`` ``(N, K)``."""
    n, d = x.shape
    k_count = mean_t.shape[1]
    diff = np.empty((d, k_count))
    weighted = np.empty(k_count)
    out[:] = 0.0
    for i in range(n):
        for a in range(d):
            for k in range(k_count):
                diff[a, k] = x[i, a] - mean_t[a, k]
        for a in range(d):
            for k in range(k_count):
                weighted[k] = resp[i, k] * diff[a, k]
            for b in range(a + 1):
                for k in range(k_count):
                    out[a, b, k] += weighted[k] * diff[b, k]
    for a in range(d):
        for b in range(a):
            for k in range(k_count):
                out[b, a, k] = out[a, b, k]
