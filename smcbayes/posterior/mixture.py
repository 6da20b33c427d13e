"""Weighted Gaussian mixture fitted by expectation-maximisation.

The importance-sampling proposal needs kernels shaped like the part of the posterior they
sit in: a posterior with two regions of high density can have a thin ridge in one
direction in the first region and a thin sheet in another direction in the second, and a
single global covariance then fits neither.  A Gaussian mixture fitted to the weighted
sample gives each region its own covariance.

EM on a weighted sample ``x_i`` with normalised weights ``w_i`` (Dempster, Laird and Rubin,
1977, with every point's contribution multiplied by its weight):

    r_ik   = alpha_k N(x_i; mu_k, S_k) / sum_j alpha_j N(x_i; mu_j, S_j)
    alpha_k = sum_i w_i r_ik
    mu_k    = sum_i w_i r_ik x_i / alpha_k
    S_k     = (n_k C_k + kappa S) / (n_k + kappa),
    C_k     = sum_i w_i r_ik (x_i - mu_k)(x_i - mu_k)^T / alpha_k,

with ``n_k = alpha_k * ESS`` the component's effective number of points and ``S`` the
sample's global covariance.  The shrinkage towards ``S`` (``kappa = d + 2`` pseudo-points)
keeps a component with few points from collapsing onto them, and it widens a component of
small mass towards the size of the whole sample: for a proposal that is a feature, since a
region the sample has barely seen is where the kernels should reach furthest.  (Shrinking
towards ``S`` rescaled to the component's own size instead, a thin second region holding 4 %
of a test posterior came out at 0.9-1.7 % and the correlations 0.15-0.28 off, against
1.2-3.5 % and 0.06-0.24 with the shrinkage above, over the same four seeds.)  The start is a weighted
k-means++ choice of means (points drawn with probability proportional to w_i times the
squared Mahalanobis distance to the nearest mean chosen so far), which reaches a distant
region of small mass that a uniform choice would miss.  A large sample is first thinned,
without bias, to a few thousand points (:func:`thin`), which keeps the fit to a fraction of
a second as the importance sample grows; the EM steps run in compiled kernels
(:mod:`._mixture_kernel`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.special import logsumexp

Array = NDArray[np.float64]

VAR_FLOOR = 1e-10
"""Least variance of a coordinate (unit cube) of the covariances the proposals are shaped by,
against a degenerate sample; it lies below the jitter of 1e-9 added to every covariance and
kernel, which keeps them positive definite and sets their least width (a unit-cube sd of
about 3e-5).  A floor must lie below the narrowest posterior the samplers meet, and data
can pin a parameter to a tiny share of its range: the demo's press-frame stiffness has a
posterior sd of 8e-5 of its log range, where a floor of 1e-4 (sd 0.01) made the kernels a
hundred times too wide and most draws fell where the posterior has no mass."""

EM_TOL = 1e-3
"""Improvement of the weighted mean log density (nats a point) below which the EM stops.
The fits shape proposals, whose weights stay exact whatever the fit.  On 34 proposal fits
of an active learning on the measured thesis trials (seven parameters, eight components,
at most 3,000 points), stopped at 1e-6 they mostly ran to the 60 iterations allowed and
reached a weighted mean log density of 8.59 nats a point on average; stopped at 1e-3 they
came 0.012 lower on average (0.070 at most) in about half the time."""


@dataclass(frozen=True)
class Mixture:
    """A fitted Gaussian mixture.

    Attributes:
        weight: component weights alpha, ``(K,)`` (sum 1).
        mean: component means, ``(K, d)``.
        cov: component covariances, ``(K, d, d)``.
    """

    weight: Array
    mean: Array
    cov: Array

    def log_joint(self, x: Array) -> Array:
        """log alpha_k + log N(x_i; mu_k, S_k), ``(N, K)``, at the points ``x`` ``(N, d)``."""
        return np.log(np.maximum(self.weight, 1e-300))[None, :] + _log_normal(x, self.mean, self.cov)

    def log_resp(self, x: Array) -> Array:
        """Log responsibilities ``(N, K)`` of the components for the points ``x`` ``(N, d)``."""
        joint = self.log_joint(x)
        return joint - logsumexp(joint, axis=1, keepdims=True)


def _log_normal(x: Array, mean: Array, cov: Array) -> Array:
    """Log density ``(N, K)`` of ``K`` normals ``(K, d)``, ``(K, d, d)`` at ``x`` ``(N, d)``."""
    d = x.shape[1]
    chol = np.linalg.cholesky(cov)
    inv = np.linalg.inv(chol)
    z = np.matmul(x[None, :, :] - mean[:, None, :], np.swapaxes(inv, 1, 2)).transpose(1, 0, 2)  # (N, K, d)
    logdet = np.sum(np.log(np.diagonal(chol, axis1=1, axis2=2)), axis=1)
    # one pass per coordinate: numpy's reduction over a last axis of a few elements is
    # several times slower, and the proposals' EM fits call this thousands of times a stage
    square = z[..., 0] * z[..., 0]
    for j in range(1, d):
        square += z[..., j] * z[..., j]
    return -0.5 * square - logdet[None, :] - 0.5 * d * np.log(2.0 * np.pi)


def _kmeans_pp(x: Array, w: Array, k: int, prec: Array, rng: np.random.Generator) -> Array:
    """``k`` starting means ``(k, d)``: weighted k-means++ in the metric ``prec``."""
    means = [x[rng.choice(x.shape[0], p=w)]]
    dist = np.full(x.shape[0], np.inf)
    for _ in range(1, k):
        diff = x - means[-1]
        dist = np.minimum(dist, np.einsum("nd,de,ne->n", diff, prec, diff))
        p = w * dist
        if not np.isfinite(p).all() or p.sum() <= 0.0:
            break
        means.append(x[rng.choice(x.shape[0], p=p / p.sum())])
    return np.array(means)


def thin(x: Array, w: Array, count: int, rng: np.random.Generator) -> tuple[Array, Array]:
    """About ``count`` of the weighted points ``x`` ``(N, d)``, ``w`` ``(N,)``, unbiased.

    Poisson sampling: point i is kept with probability p_i = min(1, c w_i), c set so that
    sum p_i = count, and its weight becomes w_i / p_i.  Heavy points are all kept; light ones
    are thinned, which a weighted EM over a growing importance sample can afford.
    """
    if x.shape[0] <= count:
        return x, w
    w = w / np.sum(w)
    with np.errstate(over="ignore", divide="ignore"):
        ratio, log_w = count / np.min(w[w > 0]), np.log(w)
    # a weight below count / DBL_MAX (about 700 nats below their sum) overflows the ratio and
    # exp(c): the bisection then runs on logarithms
    huge = not np.isfinite(ratio)

    def kept(c: float) -> Array:
        return np.exp(np.minimum(c + log_w, 0.0)) if huge else np.minimum(1.0, np.exp(c) * w)

    # sum_i min(1, c w_i) grows with c from count (at c = count) to N: bisect on log c
    lo, hi = np.log(count), (np.log(count) - np.min(log_w[w > 0]) if huge else np.log(ratio))
    for _ in range(60):
        c = 0.5 * (lo + hi)
        lo, hi = (c, hi) if kept(c).sum() < count else (lo, c)
    p = kept(hi)
    keep = rng.random(x.shape[0]) < p
    return x[keep], w[keep] / p[keep]


def fit_mixture(x: Array, w: Array, components: int, rng: np.random.Generator,
                iterations: int = 60, tol: float = EM_TOL, var_floor: float = VAR_FLOOR,
                max_points: int = 3000) -> Mixture:
    """Weighted EM fit of a Gaussian mixture (see the module docstring).

    Args:
        x: points, ``(N, d)``.
        w: non-negative weights, ``(N,)`` (normalised here).
        components: number of components K (fewer if the sample has fewer distinct points).
        rng: generator of the k-means++ start.
        iterations: most EM iterations.
        tol: stop once the weighted mean log density improves by less than this.
        var_floor: least variance of the global covariance the components shrink to (keeps a
            degenerate sample, one heavy point or a parameter at a bound, from giving a
            singular component).
        max_points: larger samples are thinned to about this many points first (:func:`thin`).

    Returns:
        The fitted mixture; with ``components == 1`` the weighted mean and (up to the
        unbiasing factor 1 / (1 - sum w_i^2) of ``S``) the weighted covariance.
    """
    keep = w > 0
    x, w = thin(x[keep], w[keep], max_points, rng)
    w = w / np.sum(w)
    n, d = x.shape
    mean0 = w @ x
    glob = (x - mean0).T @ ((x - mean0) * w[:, None]) / max(1.0 - np.sum(w * w), 1e-12)
    glob = glob + np.diag(np.maximum(var_floor - np.diag(glob), 0.0)) + 1e-9 * np.eye(d)
    ess = 1.0 / np.sum(w * w)
    kappa = d + 2.0
    k = max(1, min(components, n, int(ess // (d + 1))))
    mean = _kmeans_pp(x, w, k, np.linalg.inv(glob), rng)
    k = mean.shape[0]
    mix = Mixture(np.full(k, 1.0 / k), mean, np.broadcast_to(glob, (k, d, d)).copy())
    from smcbayes.posterior._mixture_kernel import e_step, scatter  # numba loads on first use

    resp = np.empty((n, k))  # weighted responsibilities w_i r_ik
    spread = np.empty((d, d, k))
    last = -np.inf
    for _ in range(iterations):
        chol = np.linalg.cholesky(mix.cov)
        log_det = np.sum(np.log(np.diagonal(chol, axis1=1, axis2=2)), axis=1)
        const = np.log(np.maximum(mix.weight, 1e-300)) - log_det - 0.5 * d * np.log(2.0 * np.pi)
        loglik = e_step(x, w, np.ascontiguousarray(mix.mean.T),
                        np.ascontiguousarray(np.linalg.inv(chol).transpose(1, 2, 0)), const, resp)
        alpha = np.maximum(resp.sum(axis=0), 1e-12)
        mean = (resp.T @ x) / alpha[:, None]
        scatter(x, resp, np.ascontiguousarray(mean.T), spread)
        n_k = (alpha * ess)[:, None, None]
        cov = ((n_k * spread.transpose(2, 0, 1) / alpha[:, None, None] + kappa * glob[None]) / (n_k + kappa)
               + 1e-9 * np.eye(d))
        mix = Mixture(alpha / alpha.sum(), mean, cov)
        if loglik - last < tol:
            break
        last = loglik
    return mix
