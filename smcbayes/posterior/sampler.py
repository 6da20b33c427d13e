"""emcee driver: burn-in, thinning and stopping from the integrated autocorrelation time."""

from __future__ import annotations

import logging
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from typing import Literal

import emcee
import numpy as np
from numpy.typing import NDArray

from smcbayes.progress import Progress

logger = logging.getLogger(__name__)

Array = NDArray[np.float64]
Moves = Literal["de", "stretch"]


@dataclass(frozen=True)
class SamplerSettings:
    """emcee settings.

    Attributes:
        walkers: ensemble size (at least 2 d + 2).
        max_steps: upper bound on the steps per chain.
        min_steps: steps before the stopping rule is looked at.
        check_every: steps between autocorrelation checks.
        tau_factor: stop once steps > tau_factor * tau_max ...
        tau_rtol: ... and tau changed by less than this fraction since the last check.
        moves: ``de`` (differential evolution 80 % + its snooker variant 20 %; ter Braak
            2006, Stat. Comput. 16, 239; ter Braak & Vrugt 2008, Stat. Comput. 18, 435) or
            ``stretch`` (emcee's default; Goodman & Weare 2010).  Differential evolution
            proposes along differences of walkers, so it follows curved ridges with far
            shorter autocorrelation times than the stretch move; its long jumps also reach
            distant modes, which is unwanted on a GP sample function's posterior (see
            :func:`smcbayes.posterior.active.sample`).
    """

    walkers: int = 32
    max_steps: int = 6000
    min_steps: int = 500
    check_every: int = 250
    tau_factor: float = 50.0
    tau_rtol: float = 0.05
    moves: Moves = "de"

    def __post_init__(self) -> None:
        if self.moves not in ("de", "stretch"):
            raise ValueError(f"unknown emcee moves '{self.moves}'; accepted: de, stretch")


@dataclass(frozen=True)
class Chains:
    """Post-processed chains of one ensemble.

    Attributes:
        samples: thinned samples after burn-in, ``(draws, walkers, d)`` (unit cube).
        log_prob: their log densities, ``(draws, walkers)``.
        acceptance: acceptance fraction per walker, ``(walkers,)``.
        tau: integrated autocorrelation time per parameter (steps), ``(d,)``.
        steps, burn, thin: steps run, discarded and the thinning interval.
        converged: the stopping rule was met before ``max_steps``.
        last: the walkers' positions after the last step ``(W, d)`` (W the ensemble's
            walkers), from which a later ensemble can go on (``None`` where not kept).
    """

    samples: Array
    log_prob: Array
    acceptance: Array
    tau: Array
    steps: int
    burn: int
    thin: int
    converged: bool
    last: Array | None = None


def ensemble_size(walkers: int, d: int) -> int:
    """The walkers an ensemble of ``walkers`` asked for runs in ``d`` dimensions: at least
    ``2 d + 2``."""
    return max(walkers, 2 * d + 2)


def _start(log_prob: Callable[[Array], Array], d: int, walkers: int, rng: np.random.Generator,
           centre: Array | None, at: Array | None = None) -> Array:
    """Initial walkers ``(walkers, d)``: the distinct positions ``at`` if given, else a small
    ball around ``centre`` (or uniform); a walker of non-finite density is redrawn uniformly."""
    if at is not None:
        at = np.asarray(at, dtype=float)
        if at.shape != (walkers, d):
            raise ValueError(f"the walkers' start has shape {at.shape}, not ({walkers}, {d})")
        pos = np.clip(at, 1e-6, 1 - 1e-6)
        # two walkers at one point give the snooker move a zero direction, and emcee a NaN
        if len(np.unique(pos, axis=0)) < walkers:
            raise ValueError("the walkers' start repeats a position; each walker needs its own")
    else:
        base = np.full(d, 0.5) if centre is None else np.clip(centre, 0.02, 0.98)
        pos = np.clip(base + 0.02 * rng.standard_normal((walkers, d)), 1e-6, 1 - 1e-6)
    bad = ~np.isfinite(log_prob(pos))
    if np.any(bad):
        pos[bad] = rng.random((int(bad.sum()), d))
    return pos


def run_ensemble(log_prob: Callable[[Array], Array], d: int, settings: SamplerSettings,
                 rng: np.random.Generator, centre: Array | None = None, label: str = "",
                 start: Array | None = None) -> Chains:
    """Sample ``log_prob`` (vectorised over walkers) on the unit cube with emcee.

    Stops when the chain is longer than ``tau_factor`` autocorrelation times and the
    estimate has settled, or at ``max_steps``; discards ``2 tau_max`` as burn-in and thins
    by ``max(1, tau_min / 2)``.  Progress is reported in steps through
    :class:`smcbayes.progress.Progress` (the remaining time assumes ``max_steps``, an upper
    bound when the stopping rule is met earlier).  Convergence problems are not warned about
    here but by :func:`smcbayes.posterior.summary.warnings_for`, once for all components.

    Args:
        log_prob: log density, ``(walkers, d) -> (walkers,)``; -inf outside the support.
        d: dimension of the unit cube.
        settings: ensemble size, step budget and stopping rule.
        rng: seeds the start and emcee's own generator (same seed, same chains).
        centre: start of the walkers ``(d,)`` (a small ball around it), or None: the
            cube's centre.
        label: appended to the progress description, e.g. ``" (component 2/4)"``.
        start: the walkers' start ``(W, d)`` instead of the ball around ``centre`` (W the
            ensemble's walkers, at least ``2 d + 2``; distinct rows), e.g. an earlier
            ensemble's :attr:`Chains.last` or draws of the target.
    """
    walkers = ensemble_size(settings.walkers, d)
    moves = None
    if settings.moves == "de":
        moves = [(emcee.moves.DEMove(), 0.8), (emcee.moves.DESnookerMove(), 0.2)]
    sampler = emcee.EnsembleSampler(walkers, d, log_prob, vectorize=True, moves=moves)
    # emcee draws its moves from its own RandomState: seed it from our generator
    sampler.random_state = np.random.RandomState(int(rng.integers(2**31 - 1))).get_state()
    state = _start(log_prob, d, walkers, rng, centre, start)
    old_tau, converged = np.inf, False
    with Progress(settings.max_steps, f"sampling{label}", "step") as bar:
        while sampler.iteration < settings.max_steps:
            state = sampler.run_mcmc(state, settings.check_every, progress=False)
            if sampler.iteration < settings.min_steps:
                bar.update(settings.check_every)
                continue
            tau = sampler.get_autocorr_time(tol=0)
            bar.update(settings.check_every, note=f"tau ~ {np.nanmax(tau):.0f} steps")
            ok = np.all(np.isfinite(tau)) and np.all(sampler.iteration > settings.tau_factor * tau)
            if ok and np.all(np.abs(old_tau - tau) / tau < settings.tau_rtol):
                converged = True
                break
            old_tau = tau
    logger.info("sampling%s: %d steps, %s", label, sampler.iteration,
                "converged" if converged else "stopping rule not met")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        tau = sampler.get_autocorr_time(tol=0)
    tau = np.where(np.isfinite(tau), tau, sampler.iteration / 10)
    burn = int(min(2 * np.max(tau), sampler.iteration // 2))
    thin = max(1, int(np.min(tau) / 2))
    return Chains(sampler.get_chain(discard=burn, thin=thin), sampler.get_log_prob(discard=burn, thin=thin),
                  sampler.acceptance_fraction.copy(), tau, sampler.iteration, burn, thin, converged,
                  sampler.get_last_sample().coords.copy())
