"""Importance weights: effective sample size, tempering, Pareto smoothing, weighted statistics.

All weights are handled as (unnormalised) natural-log weights, so that the tiny weights of
points far in a posterior's tail neither underflow nor dominate a sum; ``-inf`` marks a
point of zero weight (outside the prior box, or where the forward model failed).
"""

from __future__ import annotations

import warnings

import numpy as np
from numpy.typing import NDArray
from scipy.special import logsumexp

Array = NDArray[np.float64]


def ess_of(log_w: Array) -> float:
    """Effective sample size ``1 / sum w~^2`` of log weights ``(N,)`` (``w~`` normalised;
    non-finite entries count as zero weight)."""
    lw = np.asarray(log_w, dtype=float)
    lw = lw[np.isfinite(lw)]
    if lw.size == 0:
        return 0.0
    w = np.exp(lw - logsumexp(lw))
    return float(1.0 / np.sum(w * w))


def temper(log_w: Array, floor: float) -> Array:
    """``gamma * log_w`` ``(N,)`` with the largest gamma in (0, 1] whose ESS is at least
    ``floor`` (capped at half the finite weights, which any gamma near 0 reaches)."""
    lw = np.asarray(log_w, dtype=float)
    floor = min(floor, 0.5 * np.isfinite(lw).sum())
    if ess_of(lw) >= floor:
        return lw
    lo, hi = 0.0, 1.0
    # bisection: the ESS grows monotonically as gamma falls; 40 halvings reach 1e-12
    for _ in range(40):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if ess_of(mid * lw) >= floor else (lo, mid)
    return lo * lw


def weighted_cov(x: Array, w: Array) -> Array:
    """Weighted covariance ``(d, d)`` of ``x`` ``(N, d)`` with normalised weights ``w`` ``(N,)``
    (with the reliability-weights correction ``1 / (1 - sum w^2)``, unbiased for equal weights)."""
    mean = w @ x
    return (x - mean).T @ ((x - mean) * w[:, None]) / max(1.0 - np.sum(w * w), 1e-12)


def pareto_smooth(log_w: Array) -> tuple[Array, float]:
    """PSIS of the finite log weights ``(N,)``.

    Returns:
        normalised smoothed log weights ``(N,)`` (``-inf`` where the input is not finite) and
        the Pareto shape k-hat of the tail (``inf`` with fewer than 5 finite weights).
    """
    # arviz is heavy to import and needed only once a correction runs
    import arviz as az

    out = np.full(log_w.shape, -np.inf)
    ok = np.isfinite(log_w)
    if ok.sum() < 5:
        out[ok] = log_w[ok] - logsumexp(log_w[ok]) if ok.any() else 0.0
        return out, float("inf")
    with warnings.catch_warnings():
        # arviz warns itself when k-hat is large; the correction reports it in its own words
        warnings.simplefilter("ignore")
        smoothed, k = az.psislw(log_w[ok])
    out[ok] = smoothed
    return out, float(np.asarray(k).reshape(-1)[0])


def seed_weights(start: Array, known: tuple[Array, Array] | None,
                 floor: float = 20.0) -> tuple[Array, Array | None]:
    """Points ``(N0 + K', d)`` and log weights ``(N0 + K',)`` the first proposal is fitted to.

    Without ``known`` the emulator draws ``start`` ``(N0, d)`` with equal weights (``None``).
    With known exact evaluations ``known = (unit (K, d), log_target (K,))`` (the GP's
    training points, whose exact log posterior is already known), half of the weight goes
    to the K' finite ones, tempered to an ESS of at least ``floor``: the first proposal then
    also covers regions the exact likelihood favours even where the emulator misses them.
    """
    if known is None or not np.isfinite(known[1]).any():
        return start, None
    x, lt = known
    ok = np.isfinite(lt)
    lw_known = temper(lt[ok] - np.max(lt[ok]), floor)
    lw_known = np.log(0.5) + lw_known - logsumexp(lw_known)
    lw_start = np.full(start.shape[0], np.log(0.5 / start.shape[0]))
    return np.vstack([start, x[ok]]), np.concatenate([lw_start, lw_known])


def weighted_quantile(x: Array, w: Array, q: Array | list[float]) -> Array:
    """Quantiles ``(Q,)`` of ``x`` ``(N,)`` under normalised weights ``w`` ``(N,)`` at the
    probabilities ``q`` ``(Q,)`` (midpoint rule: a point's mass is centred on its value)."""
    keep = w > 0
    x, w = x[keep], w[keep]
    order = np.argsort(x)
    xs, ws = x[order], w[order]
    cdf = np.cumsum(ws) - 0.5 * ws
    cdf /= np.sum(ws)
    return np.interp(np.asarray(q, dtype=float), cdf, xs)


def weighted_moments(x: Array, w: Array) -> tuple[Array, Array, Array]:
    """Weighted mean ``(d,)``, standard deviation ``(d,)`` and correlation ``(d, d)`` of
    ``x`` ``(N, d)`` under weights ``w`` ``(N,)`` (normalised here); a constant coordinate
    gets correlation 0."""
    w = w / np.sum(w)
    mean = w @ x
    cov = (x - mean).T @ ((x - mean) * w[:, None])
    sd = np.sqrt(np.maximum(np.diag(cov), 0.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        corr = cov / np.outer(sd, sd)
    return mean, sd, np.where(np.isfinite(corr), corr, 0.0)
