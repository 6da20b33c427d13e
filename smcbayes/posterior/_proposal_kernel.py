"""numba kernel of :meth:`smcbayes.posterior.proposal.Proposal.log_pdf` (imported on first
use).

The importance samplers evaluate every proposal of a run at every draw of nonzero target
so far (the balance-heuristic denominator), so the mixture density is their largest cost
after the target.  In numpy each chunk of points builds an ``(M, n, d)`` array of whitened
offsets.  Here each point is whitened against all kernels at once with the kernels on the
innermost, contiguous axis (so the compiler vectorises over them), using the
lower-triangular inverse Cholesky factors (half the products of a full matrix), and the
kernels' densities are summed by a log-sum-exp over that axis.  Many points are shared out
in blocks over numba's threads; each point's arithmetic is the same, so the result does
not depend on their number.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange
from numpy.typing import NDArray

# numpy's error model, as in the numpy code it replaces; no fast-math: the same result
# on every machine
_jit = njit(cache=True, error_model="numpy", nogil=True)
_parallel = njit(cache=True, error_model="numpy", parallel=True, nogil=True)


@_jit
def _point(u: NDArray[np.float64], i: int, shift: NDArray[np.float64], inv: NDArray[np.float64],
           const: NDArray[np.float64], nu: float, z: NDArray[np.float64],
           log_k: NDArray[np.float64]) -> float:
    """The value of :func:`t_mixture_logpdf` at point ``i`` (``z``, ``log_k`` ``(M,)`` scratch)."""
    d = u.shape[1]
    m_kernels = shift.shape[1]
    power = -0.5 * (nu + d)
    log_k[:] = 0.0  # the squared Mahalanobis distances first
    for a in range(d):
        for m in range(m_kernels):
            z[m] = -shift[a, m]
        for b in range(a + 1):
            ub = u[i, b]
            for m in range(m_kernels):
                z[m] += inv[a, b, m] * ub
        for m in range(m_kernels):
            log_k[m] += z[m] * z[m]
    top = -math.inf
    for m in range(m_kernels):
        log_k[m] = const[m] + power * math.log1p(log_k[m] / nu)
        top = max(top, log_k[m])
    if not math.isfinite(top):  # every kernel zero (or NaN): nothing to normalise by
        return top
    total = 0.0
    for m in range(m_kernels):
        total += math.exp(log_k[m] - top)
    return top + math.log(total)


@_jit
def t_mixture_logpdf(u: NDArray[np.float64], shift: NDArray[np.float64], inv: NDArray[np.float64],
                     const: NDArray[np.float64], nu: float, out: NDArray[np.float64]) -> None:
    """Write to ``out`` ``(N,)`` the log of ``sum_m exp(const_m) (1 + r_m^2 / nu)^(-(nu + d) / 2)``
    at the points ``u`` ``(N, d)``.

    ``r_m = |A_m u - s_m|`` with ``A_m = L_m^-1`` the inverse lower Cholesky factor of
    kernel m's scale, given as ``inv`` ``(d, d, M)`` (``inv[a, b, m] = A_m[a, b]``, zero
    above the diagonal, which is skipped), and ``s_m = A_m c_m`` for its centre, given as
    ``shift`` ``(d, M)``; ``const`` ``(M,)`` holds each kernel's log normalising constant
    and log weight.
    """
    z = np.empty(shift.shape[1])
    log_k = np.empty(shift.shape[1])
    for i in range(u.shape[0]):
        out[i] = _point(u, i, shift, inv, const, nu, z, log_k)


@_parallel
def t_mixture_logpdf_parallel(u: NDArray[np.float64], shift: NDArray[np.float64], inv: NDArray[np.float64],
                              const: NDArray[np.float64], nu: float, out: NDArray[np.float64],
                              block: int) -> None:
    """:func:`t_mixture_logpdf` in blocks of ``block`` points over numba's threads."""
    n = u.shape[0]
    for b in prange((n + block - 1) // block):
        z = np.empty(shift.shape[1])
        log_k = np.empty(shift.shape[1])
        for i in range(b * block, min(n, (b + 1) * block)):
            out[i] = _point(u, i, shift, inv, const, nu, z, log_k)
