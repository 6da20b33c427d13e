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
so that no region of the prior box has zero proposal density.  The kernel scales V_m come
from a Gaussian mixture fitted to the sample (:mod:`smcbayes.posterior.mixture`): a centre
drawn from component k has
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

This module holds the adaptive loop and the weighted sample; the proposals and their fit
are in :mod:`smcbayes.posterior.proposal`, the chains in
:mod:`smcbayes.posterior.centre_chains`, and the weight arithmetic (ESS, tempering, PSIS,
weighted quantiles and moments) in :mod:`smcbayes.posterior.weights`; the names used
elsewhere are re-exported here.
"""

from __future__ import annotations

import logging
import math
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray
from scipy.special import logsumexp

from smcbayes.errors import ConvergenceWarning, UnreliablePosteriorWarning
from smcbayes.posterior.centre_chains import CentreChains
from smcbayes.posterior.proposal import CorrectionSettings, Proposal, fit_proposal
from smcbayes.posterior.weights import (
    ess_of,
    pareto_smooth,
    seed_weights,
    temper,
    weighted_moments,
    weighted_quantile,
)
from smcbayes.progress import Progress

__all__ = ["K_HAT_WARN", "CorrectionSettings", "ImportanceSample", "Proposal", "correct",
           "correction_warnings", "draws_advice", "draws_for_target", "ess_of", "fit_proposal",
           "pareto_smooth", "seed_weights", "temper", "weighted_moments", "weighted_quantile"]

logger = logging.getLogger(__name__)

Array = NDArray[np.float64]
K_HAT_WARN = 0.7
"""Pareto k-hat above which the corrected estimates are unreliable."""
DRAWS_FACTOR_MAX = 10.0
"""Beyond this many times the draws so far, an extrapolated ESS growth is no guide."""

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
        warnings: plain-language warnings about the weights (see :func:`correction_warnings`).
        ess_target: the ESS the correction aimed at.
        draws_needed: when not settled, the proposal draws in all that would reach
            ``ess_target`` at the ESS's growth over the later iterations; None when the
            sample settled or :func:`draws_for_target` has no estimate.
        target: what the weights are exact for: ``forward model`` (the correction) or
            ``emulator`` (an emulated posterior sampled by importance sampling, no forward run).
        ess_aim: the ESS the sampling drew on to once settled (0: it stopped when settled).
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
    warnings: list[str] = field(default_factory=list)
    ess_target: float = math.inf
    draws_needed: int | None = None
    target: str = "forward model"
    ess_aim: float = 0.0

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
    """Exact log posterior ``(N,)`` at ``u`` ``(N, d)``: -inf outside the cube (no forward
    run there), forward runs of ``batch`` points at a time inside; also the runs made."""
    out = np.full(u.shape[0], -np.inf)
    inside = np.flatnonzero(np.all((u >= 0.0) & (u <= 1.0), axis=1))
    for s in range(0, inside.size, batch):
        idx = inside[s:s + batch]
        val = np.asarray(log_target(u[idx]), dtype=float)
        out[idx] = np.where(np.isfinite(val), val, -np.inf)
    return out, int(inside.size)


def _iteration_sizes(settings: CorrectionSettings) -> list[int]:
    """Draws per AMIS iteration: ``per_iteration`` each, the remainder last."""
    per = max(1, min(settings.per_iteration, settings.draws))
    return [per] * (settings.draws // per) + ([settings.draws % per] if settings.draws % per else [])


@dataclass
class _Points:
    """Every point drawn so far and what the weights need of it.

    Attributes:
        unit: points, ``(N, d)``.
        target: exact log posterior, ``(N,)``.
        iteration: iteration that drew each point, ``(N,)``.
        dens: log density of each proposal used so far at every point of finite target
            (0 at the others, whose weight is zero), one ``(N,)`` row per proposal (kept
            so that a new point costs one density per proposal, not all again).
        evaluations: forward runs so far.
    """

    unit: Array
    target: Array = field(default_factory=lambda: np.empty(0))
    iteration: NDArray[np.int_] = field(default_factory=lambda: np.empty(0, dtype=int))
    dens: list[Array] = field(default_factory=list)
    evaluations: int = 0

    def add(self, t: int, new: Array, val: Array, used: int, proposals: list[Proposal]) -> None:
        """Append the draws ``new`` ``(n, d)`` of iteration ``t`` from ``proposals[-1]`` and
        their exact log posterior ``val`` ``(n,)`` (``used`` forward runs)."""
        self.unit, self.target = np.vstack([self.unit, new]), np.concatenate([self.target, val])
        self.iteration = np.concatenate([self.iteration, np.full(new.shape[0], t)])
        self.evaluations += used
        live = np.isfinite(val)
        self.dens = [np.concatenate([row, _log_pdf_where(q, new, live)])
                     for row, q in zip(self.dens, proposals[:-1], strict=True)]
        self.dens.append(_log_pdf_where(proposals[-1], self.unit, np.isfinite(self.target)))

    def log_mixture(self, sizes: list[int]) -> Array:
        """Log density ``(N,)`` of the mixture of all proposals used, each weighted by its
        share ``D_s / N`` of the draws (the balance-heuristic denominator)."""
        share = np.array(sizes, dtype=float) / sum(sizes)
        return logsumexp(np.stack(self.dens) + np.log(share)[:, None], axis=0)


def _log_pdf_where(proposal: Proposal, u: Array, live: NDArray[np.bool_]) -> Array:
    """The proposal's log density ``(N,)`` at the points ``u`` ``(N, d)`` where ``live``
    ``(N,)``, 0 elsewhere: a point whose target is zero (outside the cube, or where the
    forward model failed) has zero weight whatever its density, and such points can be
    many (16-28 % of a round's draws of the curve emulator on the measured thesis trials)."""
    out = np.zeros(u.shape[0])
    if np.any(live):
        out[live] = proposal.log_pdf(u[live])
    return out


def correct(log_target: Callable[[Array], Array], start: Array, settings: CorrectionSettings,
            rng: np.random.Generator, known: tuple[Array, Array] | None = None,
            label: str = "importance correction", runs: str = "forward runs",
            aim: float = 0.0) -> ImportanceSample:
    """AMIS from the emulator draws ``start`` ``(N0, d)`` (unit cube) to the exact posterior.

    Iterations of ``settings.per_iteration`` draws run until ``settings.draws`` are spent
    or, after at least two, the Pareto-smoothed weights are good enough (ESS and k-hat
    targets of :class:`CorrectionSettings`).  Progress is reported in draws through
    :class:`smcbayes.progress.Progress` (the remaining time assumes all ``settings.draws``
    are spent, an upper bound when the targets are met earlier).  The sample's
    :attr:`ImportanceSample.warnings` are also emitted as warnings (see
    :func:`correction_warnings`).

    Args:
        log_target: exact unnormalised log posterior, ``(P, d) -> (P,)`` (points inside
            the cube only; NaN or -inf where the forward model failed).
        start: draws of the emulated posterior.
        settings: draws, stopping targets and proposal settings.
        rng: the only source of randomness (same seed, same sample).
        known: exact log posterior already known at some points, ``(unit (K, d), (K,))``;
            they shape the first proposal (see :func:`seed_weights`), not the estimate.
        label, runs: what the progress and the log call the sampling and the target's
            evaluations.
        aim: an ESS to draw on to once the sample is settled (within ``settings.draws``);
            the sample is settled at the targets of ``settings`` all the same.
    """
    sizes = _iteration_sizes(settings)
    proposals: list[Proposal] = [fit_proposal(*seed_weights(start, known), settings,
                                              rng, settings.widen_first)]
    points = _Points(np.empty((0, start.shape[1])))
    history: list[dict[str, float]] = []
    smoothed, k_hat, settled = np.empty(0), float("inf"), False
    chains = CentreChains(proposals[0].centres[: settings.chains].copy())
    with Progress(settings.draws, label, "draw") as bar:
        for t, size in enumerate(sizes):
            new, kernel = proposals[-1].sample_indexed(size, rng)
            val, used = _evaluate(log_target, new, settings.batch)
            chains.advance(proposals[-1], new, kernel, val, rng)
            points.add(t, new, val, used, proposals)
            log_q = points.log_mixture(sizes[: t + 1])
            log_w = np.where(np.isfinite(points.target), points.target - log_q, -np.inf)
            smoothed, k_hat = pareto_smooth(log_w)
            history.append({"iteration": t, "draws": size, "evaluations": used, "ess": ess_of(smoothed),
                            "k_hat": k_hat})
            note = (f"{points.evaluations} {runs}, importance ESS {history[-1]['ess']:.0f}, "
                    f"k-hat {k_hat:.2f}")
            bar.update(size, note=note)
            logger.debug("correction iteration %d: %s", t, note)
            settled = history[-1]["ess"] >= settings.ess_target and k_hat <= settings.k_target
            if t >= 1 and settled and history[-1]["ess"] >= aim:
                break
            if t + 1 < len(sizes):
                proposals.append(_next_proposal(points, log_w, log_q, settings, rng, chains, proposals[-1]))
    sample = ImportanceSample(points.unit, points.target, smoothed, points.iteration, k_hat, ess_of(smoothed),
                              points.evaluations, history, settled, ess_target=settings.ess_target,
                              ess_aim=aim)
    sample.draws_needed = None if settled else draws_for_target(history, settings.ess_target)
    logger.info("%s: %d %s, importance ESS %.0f, k-hat %.2f%s", label, sample.evaluations, runs,
                sample.ess, sample.k_hat, "" if settled else " (not settled)")
    sample.warnings = correction_warnings(sample, stacklevel=3)
    return sample


def _next_proposal(points: _Points, log_w: Array, log_q: Array, settings: CorrectionSettings,
                   rng: np.random.Generator, chains: CentreChains, last: Proposal) -> Proposal:
    """The proposal of the next iteration, fitted to the tempered posterior pi^T (module
    docstring) with the chains' positions as its first centres; ``last`` again while no
    point has a finite weight ``log_w`` ``(N,)``."""
    if not np.isfinite(log_w).any():
        return last
    fit_w = np.where(np.isfinite(points.target), settings.fit_temperature * points.target - log_q, -np.inf)
    return fit_proposal(points.unit, fit_w, settings, rng, settings.widen, chains.position)


def draws_for_target(history: list[dict[str, float]], target: float) -> int | None:
    """Proposal draws in all after which the ESS would reach ``target``, rounded up to a
    thousand.

    With the proposals settled, the ESS of the pooled weights grows about linearly with the
    draws; the slope is a least-squares line through (draws so far, ESS) over the later half
    of the iterations in ``history`` (those of :class:`ImportanceSample`), at least three.
    A rough guide: where the later proposals keep improving, the ESS grows faster than the
    line and fewer draws suffice.  None when there is nothing to extrapolate (fewer than
    three iterations, an infinite ``target``, the target reached) or when the line does not
    rise, or would need more than :data:`DRAWS_FACTOR_MAX` times the draws so far.
    """
    drawn = np.cumsum([h["draws"] for h in history], dtype=float)
    ess = np.array([h["ess"] for h in history], dtype=float)
    if len(history) < 3 or not math.isfinite(target) or not ess[-1] < target:
        return None
    late = slice(min(len(history) // 2, len(history) - 3), None)
    slope = float(np.polyfit(drawn[late], ess[late], 1)[0])
    if not slope > 0.0:
        return None
    needed = drawn[-1] + (target - ess[-1]) / slope
    if not needed <= DRAWS_FACTOR_MAX * drawn[-1]:
        return None
    # the small offset keeps round-off from lifting an exact multiple by another thousand
    return int(math.ceil(needed / 1000.0 - 1e-9) * 1000)


def draws_advice(ess: float, target: float, draws_needed: int | None, iterations: int) -> str:
    """What to do about a correction that did not settle, in one phrase: the warning's
    and the posterior's reliability reason's (which the terminal and the report show).

    Args:
        ess: the correction's importance ESS.
        target: the ESS it aimed at (``ess_target``).
        draws_needed: :attr:`ImportanceSample.draws_needed`.
        iterations: the AMIS iterations run (too few, and the growth cannot be measured).
    """
    if not math.isfinite(target) or iterations < 3:
        return "raise --correct-draws"
    if ess >= target:
        return ("its ESS reached the target but the weights' tail (k-hat) did not settle; "
                "raise --correct-draws")
    if draws_needed is None:
        return (f"its ESS ({ess:.0f}) grew too little over the last iterations for more draws alone to "
                "reach the target; raise --refine for a better proposal")
    return (f"at the ESS's growth over the last iterations, about --correct-draws {draws_needed} "
            "would reach the ESS target (--workers or --scheduler run their forward runs in parallel)")


def correction_warnings(sample: ImportanceSample, warn: bool = True, stacklevel: int = 2) -> list[str]:
    """Plain-language warnings about the importance weights of ``sample``.

    The one place these conditions are turned into words and into warnings: a Pareto k-hat
    above :data:`K_HAT_WARN` gives an :class:`~smcbayes.errors.UnreliablePosteriorWarning`,
    otherwise a correction whose draws ran out before the ESS and k-hat targets gives a
    :class:`~smcbayes.errors.ConvergenceWarning` (one of the two at most).

    Args:
        sample: the corrected sample.
        warn: also emit each message with :func:`warnings.warn` (``False``: only return them).
        stacklevel: passed to :func:`warnings.warn` (2: the caller of this function).
    """
    out: list[tuple[str, type[Warning]]] = []
    if not sample.k_hat <= K_HAT_WARN:
        out.append((f"importance correction: Pareto k-hat {sample.k_hat:.2f} > {K_HAT_WARN}: the emulated "
                    "posterior misses part of the exact one and the corrected numbers are unreliable; "
                    "raise --correct-draws or --refine", UnreliablePosteriorWarning))
    elif not sample.settled:
        advice = draws_advice(sample.ess, sample.ess_target, sample.draws_needed, len(sample.history))
        of = f" of {sample.ess_target:.0f}" if math.isfinite(sample.ess_target) else ""
        out.append((f"importance correction did not settle within --correct-draws (importance ESS "
                    f"{sample.ess:.0f}{of}, k-hat {sample.k_hat:.2f}): the corrected numbers are "
                    f"indicative; {advice}", ConvergenceWarning))
    if warn:
        for msg, kind in out:
            warnings.warn(msg, kind, stacklevel=stacklevel)
    return [msg for msg, _ in out]
