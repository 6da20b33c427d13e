"""Importance-sampling correction of the emulated posterior with the forward model.

The emulated posterior (GP of log(loss) + emcee) is cheap but inherits the emulator's
errors: where the GP is wrong the posterior is too narrow or offset.  The forward model
itself gives the *exact* unnormalised posterior on the unit cube of the sampled
coordinates,

    pi(u) = 1[u in cube] * exp(-(N_eff / 2) * log L(u)),

(the same likelihood the emulator approximates, with the same N_eff and uniform prior),
at one batched forward run per point.  The correction uses the emulated posterior only
as a *proposal* and reweights with pi: adaptive multiple importance sampling (AMIS;
Cornuet, Marin, Mira and Robert, Scand. J. Stat. 39, 2012) with a defensive proposal

    q_t(u) = (1 - beta) * (1/M) * sum_m t_nu(u; c_m, V_m) + beta * 1[u in cube],

a mixture of M Student-t kernels (nu = 5, heavy tails) centred at points c_m drawn from
the current sample (the emcee draws of the emulator at t = 0, then the exact sample
weighted for the tempered posterior, see below), plus a share beta of the uniform prior
so that no region of the prior box has zero proposal density.  The kernel scales V_m come from a Gaussian mixture fitted to the
sample (:mod:`smcbayes.posterior.mixture`): a centre drawn from component k has
V_m = h_k^2 S_k, the component's covariance times Scott's bandwidth for the component's
share of the centres (widened at t = 0, where the emulator may be offset), and component k
gets a share of the centres proportional to sqrt(alpha_k), its mass alpha_k.  A posterior
with a second, thinner region turned another way is then drawn with kernels shaped like
each region, and a region of small mass is drawn often enough to measure it.

The first C centres (100 of 200 by default) are not redrawn but carried by Metropolis-
Hastings chains on pi.  The draw y from the kernel centred at chain c's position x is that
chain's proposal, accepted with probability

    min(1, pi(y) t(x; y, V(y)) / (pi(x) t(y; x, V(x)))),

V(x) being the kernel scale the current fit gives a centre at x (the scale of its most
responsible mixture component), so the chains reuse the draws and cost no forward run of
their own.  A posterior can have a long arm that the weighted sample sees mostly near its
root; centres drawn afresh from the sample stay there, while a chain that reaches the
arm walks along it and takes its kernel with it.  Chains cannot jump to a separate region,
so the fresh centres top each component up to its share sqrt(alpha_k).  The centres may
depend on earlier draws: the weights below use the densities of the proposals actually
drawn from (consistent as the draws per iteration grow; Marin, Pudlo and Sedki,
Bernoulli 25, 2019).

After each iteration every point evaluated so far, u_i with i = 1..N, is weighted against
the mixture of all proposals used (the "deterministic mixture" or balance-heuristic
weights, which recycle every forward run):

    log w_i = log pi(u_i) - log sum_s (D_s / N) q_s(u_i),

D_s being the number of points drawn from q_s.  The next proposal is fitted not to pi but
to the tempered posterior pi^T (T = ``fit_temperature``, 1/2 by default), the same points
weighted by pi(u_i)^T / sum_s (D_s / N) q_s(u_i).  Fitted to pi, the proposals stay where
mass has already been found: a region that the draws see only at its edge keeps few
kernels, and its mass comes out too small in the same direction on every seed (a flat arm
of 4.4 % of the accuracy benchmark's posterior came out at 1.4-2.8 % over six seeds,
while the ESS reached 2000 and k-hat stayed low).  pi^T lowers the contrast between
densities (a ratio r becomes r^T), so the proposals spread into such regions; for a
Gaussian posterior pi^(1/2) is sqrt(2) times wider (the thesis posterior still reached
its ESS target after the same number of forward runs).  Those weights are further
tempered, w^gamma with the largest gamma <= 1 that keeps an effective sample size of at
least ``ess_floor``, so that a few heavy points cannot collapse the fit.  The chains
above still target pi; the fresh centres, the kernel scales and the components' masses
alpha_k follow pi^T, so a region of small mass gains twice, from T and from
sqrt(alpha_k).  The estimates always use the weights of pi itself.

The final weights are Pareto-smoothed (PSIS; Vehtari, Simpson, Gelman, Yao and Gabry,
JMLR 25, 2024): the largest raw weights are replaced by expected order statistics of a
generalised Pareto distribution fitted to them.  Its shape k-hat is the reliability
diagnostic: k-hat < 0.5 the weighted estimates are reliable, 0.5-0.7 usable, > 0.7 the
proposal misses part of the posterior (more draws or refinement needed).  The importance
effective sample size is ESS = 1 / sum_i w~_i^2 with w~ the normalised smoothed weights.
Iterations stop once ESS and k-hat meet their targets (after at least two) or when the
draws are spent.
"""

from __future__ import annotations

import sys
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray
from scipy.special import gammaln, logsumexp

from smcbayes.errors import ConfigError
from smcbayes.posterior.mixture import fit_mixture

Array = NDArray[np.float64]
K_HAT_WARN = 0.7
"""Pareto k-hat above which the corrected estimates are unreliable."""


@dataclass(frozen=True)
class CorrectionSettings:
    """Settings of the importance-sampling correction.

    Attributes:
        draws: most proposal draws in total (points outside the prior box cost no forward run).
        per_iteration: proposal draws per AMIS iteration.
        ess_target, k_target: stop early, after at least two iterations, once the smoothed
            weights have an ESS >= ess_target and a Pareto k-hat <= k_target.  An ESS of
            2000, not a few hundred: a second region holding a few per cent of the posterior
            moves the correlations by up to 0.2, and its estimated mass settles only as the
            proposals keep drawing there; neither the ESS nor k-hat sees a region that is
            under-drawn (``benchmarks/posterior_accuracy.py``).
        centres: kernels M of the mixture proposal.
        nu: degrees of freedom of the Student-t kernels.
        defensive: share beta of the uniform prior in every proposal.  A quarter: the
            emulator can miss a second region of high posterior density altogether, and only
            the uniform draws can find it (with 10 % the corrected correlations of a
            two-region test posterior were off by 0.18-0.29 over four seeds, with 25 % by
            0.10-0.21, for a similar number of forward runs: 2,983-3,743 against 2,081-4,258).
        widen_first: bandwidth factor of the first proposal (fitted to emulator draws).
        widen: bandwidth factor of the later proposals.
        ess_floor: minimum effective sample size of the tempered weights a proposal is fitted to.
        fit_temperature: exponent T of the tempered posterior pi^T the proposals are fitted
            to (see the module docstring; 1: fitted to pi).  With 1/2 the accuracy
            benchmark's quantile and correlation errors over eight seeds (fixed emulator
            start) fell from 0.086 and 0.130 on average to 0.069 and 0.081 in its first case
            and from 0.057 and 0.116 to 0.053 and 0.097 in its second.  The cost: the draws now
            run out on both (10,200-10,900 forward runs, were 8,900-10,900), and the coverage
            benchmark spends 7,200 runs per dataset (was 5,500); the thesis posterior still
            stops at ESS 2000 after about 2,300 runs.
        local: kernels shaped by the centres' nearest neighbours (see :func:`fit_proposal`).
        clusters: components of the Gaussian mixture that shapes the kernels and shares out
            the centres (see :func:`fit_proposal`); 1: one global covariance, centres drawn
            in proportion to the weights.  With 1, the accuracy benchmark's thin second
            region was drawn with kernels shaped for the main one: correlation errors of
            0.15-0.21 remained after 10,500 forward runs (four seeds).
        chains: centres carried by Metropolis-Hastings chains on the exact posterior (the
            rest are drawn afresh every iteration; at most ``centres``; 0: none).  A chain
            moves at most once per iteration, with the first draw of its own kernel, so it
            costs no forward run; a chain that reaches a long arm of the posterior walks
            along it (see the module docstring and ``benchmarks/posterior_accuracy.py``).
            The correction then needs more draws to reach its ESS target, since chains
            started where the emulator was wrong walk in slowly.
        batch: points per forward call.
    """

    draws: int = 14000
    per_iteration: int = 500
    ess_target: float = 2000.0
    k_target: float = 0.5
    centres: int = 200
    nu: float = 5.0
    defensive: float = 0.25
    widen_first: float = 1.5
    widen: float = 1.0
    ess_floor: float = 50.0
    batch: int = 500
    local: bool = False
    clusters: int = 8
    chains: int = 100
    fit_temperature: float = 0.5

    def __post_init__(self) -> None:
        if not 0.0 < self.fit_temperature <= 1.0:
            raise ConfigError(f"fit_temperature must lie in (0, 1], got {self.fit_temperature}")


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

    def log_pdf(self, u: Array, chunk: int = 1000) -> Array:
        """Log density at ``u`` ``(N, d)``, ``(N,)``."""
        u = np.atleast_2d(u)
        m, d = self.centres.shape
        nu = self.nu
        const = _log_t_norm(self.chol, nu) - np.log(m)
        inv = np.linalg.inv(self.chol)  # (M, d, d)
        out = np.empty(u.shape[0])
        for s in range(0, u.shape[0], chunk):
            diff = u[s:s + chunk, None, :] - self.centres[None, :, :]  # (n, M, d)
            z = np.einsum("mde,nme->nmd", inv, diff)
            maha = np.sum(z * z, axis=2)
            out[s:s + chunk] = logsumexp(const[None, :] - 0.5 * (nu + d) * np.log1p(maha / nu), axis=1)
        inside = np.all((u >= 0.0) & (u <= 1.0), axis=1)
        log_uniform = np.where(inside, 0.0, -np.inf)
        with np.errstate(divide="ignore"):
            return np.logaddexp(np.log1p(-self.defensive) + out, np.log(self.defensive) + log_uniform)


def ess_of(log_w: Array) -> float:
    """Effective sample size 1 / sum w~^2 of (unnormalised) log weights."""
    lw = np.asarray(log_w, dtype=float)
    lw = lw[np.isfinite(lw)]
    if lw.size == 0:
        return 0.0
    w = np.exp(lw - logsumexp(lw))
    return float(1.0 / np.sum(w * w))


def temper(log_w: Array, floor: float) -> Array:
    """``gamma * log_w`` with the largest gamma in (0, 1] whose ESS is at least ``floor``."""
    lw = np.asarray(log_w, dtype=float)
    floor = min(floor, 0.5 * np.isfinite(lw).sum())
    if ess_of(lw) >= floor:
        return lw
    lo, hi = 0.0, 1.0
    for _ in range(40):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if ess_of(mid * lw) >= floor else (lo, mid)
    return lo * lw


def _weighted_cov(x: Array, w: Array) -> Array:
    """Weighted covariance ``(d, d)`` of ``x`` ``(N, d)`` with normalised weights ``w``."""
    mean = w @ x
    return (x - mean).T @ ((x - mean) * w[:, None]) / max(1.0 - np.sum(w * w), 1e-12)


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
        out[i] = _weighted_cov(x[near], wn)
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
    keeping the global spread as a floor.  ``fixed`` ``(C, d)`` are the positions of the
    first centres (the chains' of :func:`correct`); the proposal's ``chol_at`` then gives
    the scale a centre would get at any position.
    """
    n, d = u.shape
    lw = np.zeros(n) if log_w is None else temper(log_w, settings.ess_floor)
    ok = np.isfinite(lw)
    w = np.zeros(n)
    w[ok] = np.exp(lw[ok] - logsumexp(lw[ok]))
    cov = _weighted_cov(u, w)
    # a floor keeps a degenerate sample (one heavy point, a parameter at a bound) from
    # producing a singular kernel
    cov += np.diag(np.maximum(1e-4 - np.diag(cov), 0.0)) + 1e-9 * np.eye(d)
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
        scale_at = _with_local(scale_at if scale_at is not None else (lambda p: np.broadcast_to(const, (p.shape[0], d, d))),
                               u, w, cov, k, (widen * 1.5) ** 2)
    chol_at = None if scale_at is None else (lambda p: np.linalg.cholesky(scale_at(p)))
    return Proposal(centres, np.linalg.cholesky(scale), settings.nu, settings.defensive, chol_at)


@dataclass
class ImportanceSample:
    """Weighted exact posterior sample.

    Attributes:
        unit: points in the unit cube, ``(N, d)``.
        log_target: exact log posterior (unnormalised) at the points, ``(N,)``; -inf outside
            the cube or where the forward model failed.
        log_weight: Pareto-smoothed normalised log weights, ``(N,)``.
        iteration: AMIS iteration that drew each point, ``(N,)``.
        k_hat: Pareto shape of the weight tail.
        ess: importance effective sample size of the smoothed weights.
        evaluations: forward evaluations used (points inside the cube).
        history: per iteration: draws, evaluations, ESS and k-hat of the smoothed weights so far.
        settled: the ESS and k-hat targets were met (else the draws ran out first).
    """

    unit: Array
    log_target: Array
    log_weight: Array
    iteration: Array
    k_hat: float
    ess: float
    evaluations: int
    history: list[dict[str, float]] = field(default_factory=list)
    settled: bool = False

    @property
    def weights(self) -> Array:
        """Normalised weights, ``(N,)``."""
        return np.exp(self.log_weight)

    def resample(self, count: int, rng: np.random.Generator) -> Array:
        """Equal-weight set of ``count`` points ``(count, d)`` (systematic resampling)."""
        cdf = np.cumsum(self.weights)
        cdf /= cdf[-1]
        pos = (rng.random() + np.arange(count)) / count
        return self.unit[np.minimum(np.searchsorted(cdf, pos), self.unit.shape[0] - 1)]


def _evaluate(log_target: Callable[[Array], Array], u: Array, batch: int) -> tuple[Array, int]:
    """Exact log posterior at ``u`` ``(N, d)``: -inf outside the cube, forward runs inside."""
    out = np.full(u.shape[0], -np.inf)
    inside = np.flatnonzero(np.all((u >= 0.0) & (u <= 1.0), axis=1))
    for s in range(0, inside.size, batch):
        idx = inside[s:s + batch]
        val = np.asarray(log_target(u[idx]), dtype=float)
        out[idx] = np.where(np.isfinite(val), val, -np.inf)
    return out, int(inside.size)


def pareto_smooth(log_w: Array) -> tuple[Array, float]:
    """PSIS of the finite log weights; returns normalised log weights ``(N,)`` and k-hat."""
    import arviz as az

    out = np.full(log_w.shape, -np.inf)
    ok = np.isfinite(log_w)
    if ok.sum() < 5:
        out[ok] = log_w[ok] - logsumexp(log_w[ok]) if ok.any() else 0.0
        return out, float("inf")
    with warnings.catch_warnings():
        # arviz warns itself when k-hat is large; the stage reports it in its own words
        warnings.simplefilter("ignore")
        smoothed, k = az.psislw(log_w[ok])
    out[ok] = smoothed
    return out, float(np.asarray(k).reshape(-1)[0])


def seed_weights(start: Array, known: tuple[Array, Array] | None, floor: float = 20.0) -> tuple[Array, Array | None]:
    """Points and log weights the first proposal is fitted to.

    Without ``known`` the emulator draws ``start`` with equal weights.  With known exact
    evaluations ``known = (unit (K, d), log_target (K,))`` (the GP's training points, whose
    exact log posterior is already known), half of the weight goes to them, tempered to an
    ESS of at least ``floor``: the first proposal then also covers regions the exact
    likelihood favours even where the emulator misses them.
    """
    if known is None or not np.isfinite(known[1]).any():
        return start, None
    x, lt = known
    ok = np.isfinite(lt)
    lw_known = temper(lt[ok] - np.max(lt[ok]), floor)
    lw_known = np.log(0.5) + lw_known - logsumexp(lw_known)
    lw_start = np.full(start.shape[0], np.log(0.5 / start.shape[0]))
    return np.vstack([start, x[ok]]), np.concatenate([lw_start, lw_known])


def _log_t(x: Array, centre: Array, chol: Array, nu: float) -> Array:
    """Log density ``(n,)`` of Student-t kernels (centres ``(n, d)``, Cholesky factors
    ``(n, d, d)``, ``nu`` degrees of freedom) at the points ``x`` ``(n, d)``, pairwise."""
    d = x.shape[1]
    z = np.linalg.solve(chol, (x - centre)[:, :, None])[:, :, 0]
    return _log_t_norm(chol, nu) - 0.5 * (nu + d) * np.log1p(np.sum(z * z, axis=1) / nu)


@dataclass
class _Chains:
    """Metropolis-Hastings chains on the exact posterior that carry the first centres.

    A draw from the Student-t kernel centred at a chain's position is that chain's proposal
    (see :meth:`advance`), so each iteration moves every chain whose kernel was drawn from
    at no extra forward run.  A chain starts at a centre of the first proposal (an emulator
    draw or a GP training point) with an unknown target value and accepts its first draw
    with a finite target.

    Attributes:
        position: chain positions in the unit cube, ``(C, d)``.
        log_target: exact log posterior at the positions, ``(C,)`` (-inf before the first move).
    """

    position: Array
    log_target: Array = field(default_factory=lambda: np.empty(0))

    def __post_init__(self) -> None:
        if self.log_target.size != self.position.shape[0]:
            self.log_target = np.full(self.position.shape[0], -np.inf)

    def advance(self, proposal: Proposal, draws: Array, kernel: Array, log_target: Array,
                rng: np.random.Generator) -> None:
        """One Metropolis-Hastings step per chain from the ``draws`` ``(n, d)`` of ``proposal``,
        the kernel each came from ``(n,)`` and their exact log posterior ``(n,)``.

        Chain c at x proposes y, the first draw of kernel c, and accepts with probability
        ``min(1, pi(y) t(x; y, V(y)) / (pi(x) t(y; x, V(x))))``, V the kernel scale the fit
        gives a centre at that position (``proposal.chol_at``; equal scales cancel).  A chain
        whose kernel is not centred at its position (a proposal kept from an earlier
        iteration) does not move.
        """
        count = min(self.position.shape[0], proposal.centres.shape[0])
        centred = np.all(proposal.centres[:count] == self.position[:count], axis=1)
        own = np.flatnonzero((kernel >= 0) & (kernel < count))
        own = own[centred[kernel[own]]]
        _, first = np.unique(kernel[own], return_index=True)
        pick = own[first]
        chain, y = kernel[pick], draws[pick]
        with np.errstate(invalid="ignore"):
            log_ratio = log_target[pick] - self.log_target[chain]
        if proposal.chol_at is not None and pick.size:
            x = self.position[chain]
            log_ratio += (_log_t(x, y, proposal.chol_at(y), proposal.nu)
                          - _log_t(y, x, proposal.chol[chain], proposal.nu))
        move = np.isfinite(log_target[pick]) & (np.log(rng.random(pick.size)) < np.nan_to_num(log_ratio, nan=-np.inf))
        self.position[chain[move]], self.log_target[chain[move]] = y[move], log_target[pick][move]


def correct(log_target: Callable[[Array], Array], start: Array, settings: CorrectionSettings,
            rng: np.random.Generator, known: tuple[Array, Array] | None = None) -> ImportanceSample:
    """AMIS from the emulator draws ``start`` ``(N0, d)`` (unit cube) to the exact posterior.

    Iterations of ``settings.per_iteration`` draws run until ``settings.draws`` are spent
    or, after at least two, the Pareto-smoothed weights are good enough (ESS and k-hat
    targets of :class:`CorrectionSettings`).

    Args:
        log_target: exact unnormalised log posterior, ``(P, d) -> (P,)`` (points inside
            the cube only; NaN or -inf where the forward model failed).
        start: draws of the emulated posterior.
        known: exact log posterior already known at some points, ``(unit (K, d), (K,))``;
            they shape the first proposal (see :func:`seed_weights`), not the estimate.
    """
    d = start.shape[1]
    per = max(1, min(settings.per_iteration, settings.draws))
    sizes = [per] * (settings.draws // per) + ([settings.draws % per] if settings.draws % per else [])
    proposals: list[Proposal] = [fit_proposal(*seed_weights(start, known), settings, rng, settings.widen_first)]
    unit, target, it = np.empty((0, d)), np.empty(0), np.empty(0, dtype=int)
    evaluations, history = 0, []
    dens: list[Array] = []  # log q_s at every point so far, one row per proposal
    smoothed, k_hat, settled = np.empty(0), float("inf"), False
    chains = _Chains(proposals[0].centres[: settings.chains].copy())
    for t, size in enumerate(sizes):
        new, kernel = proposals[-1].sample_indexed(size, rng)
        val, used = _evaluate(log_target, new, settings.batch)
        chains.advance(proposals[-1], new, kernel, val, rng)
        unit, target = np.vstack([unit, new]), np.concatenate([target, val])
        it = np.concatenate([it, np.full(size, t)])
        evaluations += used
        dens = [np.concatenate([row, q.log_pdf(new)]) for row, q in zip(dens, proposals, strict=False)]
        dens.append(proposals[-1].log_pdf(unit))
        share = np.array(sizes[: t + 1], dtype=float) / sum(sizes[: t + 1])
        log_q = logsumexp(np.stack(dens) + np.log(share)[:, None], axis=0)
        log_w = np.where(np.isfinite(target), target - log_q, -np.inf)
        smoothed, k_hat = pareto_smooth(log_w)
        history.append({"iteration": t, "draws": size, "evaluations": used, "ess": ess_of(smoothed), "k_hat": k_hat})
        print(f"\r  correcting: {evaluations} forward evaluations, importance ESS {history[-1]['ess']:.0f}, "
              f"k-hat {k_hat:.2f}", end="", file=sys.stderr, flush=True)
        settled = history[-1]["ess"] >= settings.ess_target and k_hat <= settings.k_target
        if t >= 1 and settled:
            break
        if t + 1 < len(sizes):
            fitted = np.isfinite(log_w).any()
            fit_w = np.where(np.isfinite(target), settings.fit_temperature * target - log_q, -np.inf)
            proposals.append(fit_proposal(unit, fit_w, settings, rng, settings.widen, chains.position)
                             if fitted else proposals[-1])
    print("", file=sys.stderr)
    return ImportanceSample(unit, target, smoothed, it, k_hat, ess_of(smoothed), evaluations, history, settled)


def weighted_quantile(x: Array, w: Array, q: Array | list[float]) -> Array:
    """Quantiles of ``x`` ``(N,)`` under normalised weights ``w`` ``(N,)`` (midpoint rule)."""
    keep = w > 0
    x, w = x[keep], w[keep]
    order = np.argsort(x)
    xs, ws = x[order], w[order]
    cdf = np.cumsum(ws) - 0.5 * ws
    cdf /= np.sum(ws)
    return np.interp(np.asarray(q, dtype=float), cdf, xs)


def weighted_moments(x: Array, w: Array) -> tuple[Array, Array, Array]:
    """Weighted mean ``(d,)``, standard deviation ``(d,)`` and correlation ``(d, d)`` of ``x`` ``(N, d)``."""
    w = w / np.sum(w)
    mean = w @ x
    cov = (x - mean).T @ ((x - mean) * w[:, None])
    sd = np.sqrt(np.maximum(np.diag(cov), 0.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        corr = cov / np.outer(sd, sd)
    return mean, sd, np.where(np.isfinite(corr), corr, 0.0)
