"""Defensive Student-t mixture proposals of the importance correction and their fit.

A proposal is ``(1 - beta) * (1/M) * sum_m t_nu(u; c_m, V_m) + beta * 1[u in cube]`` on the
unit cube of the sampled coordinates; :func:`fit_proposal` chooses the centres c_m and the
kernel scales V_m from a weighted sample (see :mod:`smcbayes.posterior.correct` for why).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray
from scipy.special import gammaln, logsumexp

from smcbayes.config import CorrectionSpec
from smcbayes.posterior._blocks import BLOCK, PARALLEL_ROWS
from smcbayes.posterior.mixture import VAR_FLOOR, fit_mixture
from smcbayes.posterior.threads import in_worker
from smcbayes.posterior.weights import ess_of, temper, weighted_cov

Array = NDArray[np.float64]


CorrectionSettings = CorrectionSpec
"""The correction's settings are the ``[posterior.correction]`` table (one model, one set of
defaults, in :mod:`smcbayes.config.settings`)."""


def _log_t_norm(chol: Array, nu: float) -> Array:
    """Log normalising constants ``(M,)`` of d-variate Student-t kernels with Cholesky
    factors ``chol`` ``(M, d, d)`` of their scale matrices."""
    d = chol.shape[-1]
    logdet = np.sum(np.log(np.diagonal(chol, axis1=1, axis2=2)), axis=1)
    return gammaln(0.5 * (nu + d)) - gammaln(0.5 * nu) - 0.5 * d * np.log(nu * np.pi) - logdet


@dataclass(frozen=True)
class Proposal:
    """Defensive mixture of Student-t kernels on the unit cube.

    Attributes:
        centres: kernel centres, ``(M, d)``.
        chol: Cholesky factors of the kernel scale matrices, ``(M, d, d)``.
        nu: degrees of freedom.
        defensive: share of the uniform density on the unit cube.
        chol_at: Cholesky factors ``(n, d, d)`` of the scale a kernel centred at each of the
            points ``(n, d)`` would get from the same fit, when the scale depends on the
            centre's position (the Hastings term of the chains); None when it does not.
    """

    centres: Array
    chol: Array
    nu: float
    defensive: float
    chol_at: Callable[[Array], Array] | None = field(default=None, compare=False)

    def sample(self, count: int, rng: np.random.Generator) -> Array:
        """``count`` points ``(count, d)`` (some may fall outside the cube)."""
        return self.sample_indexed(count, rng)[0]

    def sample_indexed(self, count: int, rng: np.random.Generator) -> tuple[Array, Array]:
        """``count`` points ``(count, d)`` and the kernel each came from ``(count,)`` (-1: uniform)."""
        m, d = self.centres.shape
        kernel = np.full(count, -1, dtype=np.intp)
        uniform = rng.random(count) < self.defensive
        out = rng.random((count, d))
        k = int((~uniform).sum())
        if k:
            idx = rng.integers(m, size=k)
            z = np.einsum("kde,ke->kd", self.chol[idx], rng.standard_normal((k, d)))
            z *= np.sqrt(self.nu / rng.chisquare(self.nu, size=(k, 1)))
            out[~uniform] = self.centres[idx] + z
            kernel[~uniform] = idx
        return out, kernel

    def log_pdf(self, u: Array) -> Array:
        """Log density ``(N,)`` at the points ``u`` ``(N, d)`` (:mod:`._proposal_kernel`)."""
        from smcbayes.posterior._proposal_kernel import (  # numba loads on first use
            t_mixture_logpdf,
            t_mixture_logpdf_parallel,
        )

        u = np.ascontiguousarray(np.atleast_2d(u), dtype=float)
        const = _log_t_norm(self.chol, self.nu) - np.log(self.centres.shape[0])
        inv = np.linalg.inv(self.chol)  # (M, d, d): L_m^-1, lower triangular
        shift = np.einsum("mde,me->dm", inv, self.centres)
        out = np.empty(u.shape[0])
        args = (u, np.ascontiguousarray(shift), np.ascontiguousarray(inv.transpose(1, 2, 0)), const,
                float(self.nu), out)
        if len(u) >= PARALLEL_ROWS and not in_worker():
            t_mixture_logpdf_parallel(*args, BLOCK)
        else:
            t_mixture_logpdf(*args)
        inside = np.all((u >= 0.0) & (u <= 1.0), axis=1)
        log_uniform = np.where(inside, 0.0, -np.inf)
        with np.errstate(divide="ignore"):
            return np.logaddexp(np.log1p(-self.defensive) + out, np.log(self.defensive) + log_uniform)


def _local_covs(u: Array, w: Array, centres: Array, cov: Array, neighbours: int) -> Array:
    """Weighted covariance of the ``neighbours`` nearest points (global Mahalanobis metric)
    around each centre, ``(M, d, d)``: the kernels follow a curved ridge."""
    live = w > 0
    x, wl = u[live], w[live]
    k = min(neighbours, x.shape[0])
    prec = np.linalg.inv(cov)
    out = np.empty((centres.shape[0], u.shape[1], u.shape[1]))
    for i, c in enumerate(centres):
        diff = x - c
        near = np.argpartition(np.einsum("nd,de,ne->n", diff, prec, diff), k - 1)[:k]
        wn = wl[near] / wl[near].sum()
        out[i] = weighted_cov(x[near], wn)
    return out


def _cluster_centres(u: Array, w: Array, m: int, m_eff: float, clusters: int, widen: float,
                     rng: np.random.Generator, fixed: Array | None = None,
                     ) -> tuple[Array, Array, Callable[[Array], Array]]:
    """Centres ``(m, d)``, kernel scales ``(m, d, d)`` and the scale function of fixed centres
    from a Gaussian mixture fitted to the weighted sample ``u`` ``(N, d)``, ``w`` ``(N,)``.

    The first centres are ``fixed`` ``(C, d)`` when given; they get the scale of the
    component most responsible at their position, ``scale_at(points (n, d)) -> (n, d, d)``.

    Component k receives a share ``s_k = sqrt(alpha_k) / sum_j sqrt(alpha_j)`` of the centres
    (more than its mass alpha_k when that is small, so that a region holding a few per cent
    of the posterior is drawn often enough for its mass to be estimated), drawn from its
    points with probabilities ``w_i r_ik``; a centre of component k gets the scale
    ``(widen h_k)^2 S_k`` with Scott's factor ``h_k = (s_k m_eff)^(-1 / (d + 4))``.
    """
    d = u.shape[1]
    mix = fit_mixture(u, w, clusters, rng)
    resp = np.exp(mix.log_resp(u)) * w[:, None]  # (N, K)
    share = np.sqrt(mix.weight) / np.sum(np.sqrt(mix.weight))
    fixed = None if fixed is None else fixed[:m]
    owner = None if fixed is None else np.argmax(mix.log_joint(fixed), axis=1)
    held = np.zeros(share.size) if owner is None else np.bincount(owner, minlength=share.size)
    # the fresh centres top each component up to its share: chains cannot jump to a
    # separate region, so one the emulator missed would otherwise get only part of it
    deficit = np.maximum(share * m - held, 0.0)
    top_up = deficit / deficit.sum() if deficit.sum() > 0.0 else share
    comp = rng.choice(share.size, size=m, p=top_up)
    centres = np.empty((m, d))
    for k in np.unique(comp):
        # a component whose responsibilities underflow everywhere falls back to the weights
        p = resp[:, k] / resp[:, k].sum() if resp[:, k].sum() > 0.0 else w
        centres[comp == k] = u[rng.choice(u.shape[0], size=int(np.sum(comp == k)), p=p)]
    h = widen * np.maximum(share * m_eff, 1.0) ** (-1.0 / (d + 4))

    def scale_of(k: NDArray[np.intp]) -> Array:
        return (h[k, None, None] ** 2) * mix.cov[k] + 1e-9 * np.eye(d)

    if fixed is not None:
        centres[: fixed.shape[0]] = fixed
        comp[: fixed.shape[0]] = owner
    return centres, scale_of(comp), lambda points: scale_of(np.argmax(mix.log_joint(points), axis=1))


def _with_local(base: Callable[[Array], Array], u: Array, w: Array, cov: Array, neighbours: int,
                factor: float) -> Callable[[Array], Array]:
    """The kernel scale at given centres ``(n, d) -> (n, d, d)``: half ``base``, half ``factor``
    times the covariance of the centres' weighted nearest neighbours (see :func:`_local_covs`)."""
    def scale_at(points: Array) -> Array:
        local = _local_covs(u, w, points, cov, neighbours)
        return 0.5 * base(points) + 0.5 * factor * local + 1e-9 * np.eye(u.shape[1])
    return scale_at


def fit_proposal(u: Array, log_w: Array | None, settings: CorrectionSettings, rng: np.random.Generator,
                 widen: float = 1.0, fixed: Array | None = None) -> Proposal:
    """Mixture proposal fitted to a (weighted) sample ``u`` ``(N, d)``.

    With ``settings.clusters > 1``, a Gaussian mixture is fitted to the sample with the
    tempered weights, and centres and kernel scales come from its components (see
    :func:`_cluster_centres`).  Otherwise the centres are drawn from the sample with the
    tempered weights, and the kernel scales are the weighted covariance times Scott's
    bandwidth squared (for the effective number of centres) times ``widen`` squared.  With
    ``settings.local`` (weighted samples only), half of it is replaced by the covariance of
    each centre's weighted nearest neighbours, so the kernels follow a curved ridge while
    keeping the global spread as a floor.

    Args:
        u: sample in the unit cube, ``(N, d)``.
        log_w: its unnormalised log weights ``(N,)`` (``-inf``: zero weight), or ``None``
            for equal weights; tempered to an ESS of at least ``settings.ess_floor``.
        settings: the correction's settings (centres, clusters, kernels, ``local``).
        rng: draws the centres (and seeds the mixture fit).
        widen: factor on the kernels' bandwidth (dimensionless).
        fixed: positions ``(C, d)`` of the first centres (the Metropolis-Hastings chains of
            :func:`smcbayes.posterior.correct.correct`); the proposal's ``chol_at`` then
            gives the scale a centre would get at any position.
    """
    n, d = u.shape
    lw = np.zeros(n) if log_w is None else temper(log_w, settings.ess_floor)
    ok = np.isfinite(lw)
    w = np.zeros(n)
    w[ok] = np.exp(lw[ok] - logsumexp(lw[ok]))
    cov = weighted_cov(u, w)
    # a floor keeps a degenerate sample (one heavy point, a parameter at a bound) from
    # producing a singular kernel
    cov += np.diag(np.maximum(VAR_FLOOR - np.diag(cov), 0.0)) + 1e-9 * np.eye(d)
    m = min(settings.centres, n)
    ess = ess_of(lw) if log_w is not None else float(n)
    m_eff = min(m, ess)
    scale_at: Callable[[Array], Array] | None = None
    if settings.clusters > 1:
        centres, scale, scale_at = _cluster_centres(u, w, m, m_eff, settings.clusters, widen, rng, fixed)
    else:
        centres = u[rng.choice(n, size=m, replace=True, p=w)]
        if fixed is not None:
            centres[: min(m, fixed.shape[0])] = fixed[:m]
        const = (widen * max(m_eff, 1.0) ** (-1.0 / (d + 4))) ** 2 * cov
        scale = np.broadcast_to(const, (m, d, d)).copy()
    if log_w is not None and settings.local and ess >= 4 * d:
        k = max(4 * d, int(ess // 2))
        scale = 0.5 * scale + 0.5 * _local_covs(u, w, centres, cov, k) * (widen * 1.5) ** 2 + 1e-9 * np.eye(d)
        scale_at = _with_local(scale_at if scale_at is not None
                               else (lambda p: np.broadcast_to(const, (p.shape[0], d, d))),
                               u, w, cov, k, (widen * 1.5) ** 2)
    chol_at = None if scale_at is None else (lambda p: np.linalg.cholesky(scale_at(p)))
    return Proposal(centres, np.linalg.cholesky(scale), settings.nu, settings.defensive, chol_at)


def log_t_pairwise(x: Array, centre: Array, chol: Array, nu: float) -> Array:
    """Log density ``(n,)`` of Student-t kernels (centres ``(n, d)``, Cholesky factors
    ``(n, d, d)``, ``nu`` degrees of freedom) at the points ``x`` ``(n, d)``, pairwise."""
    d = x.shape[1]
    z = np.linalg.solve(chol, (x - centre)[:, :, None])[:, :, 0]
    return _log_t_norm(chol, nu) - 0.5 * (nu + d) * np.log1p(np.sum(z * z, axis=1) / nu)
