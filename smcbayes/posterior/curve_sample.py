"""Sampling the curve emulator's posterior, without a forward run: the emcee chains that
start it, the adaptive importance sampling of the emulated posterior (the correction's
algorithm with the emulator as its target) and the reported posterior, which pools the mean's
sample with the posteriors of GP sample functions (:mod:`smcbayes.posterior.curve_spread`);
and how far the emulated posterior moved between two emulators (:func:`quantile_shift`).

The emulated likelihood is that of the expected loss (:data:`EXPECTED_LOSS`).  The emcee
chains start at the best point, or, after the active learning's rounds, at draws of the last
round's posterior, which then join their draws in the importance sampling's first proposal.
Started at the best point they under-sample a flat arm of the posterior: on the accuracy
benchmark's first case they put 1.2 % of the mass where the emulated posterior, sampled by
importance, puts 9-10 % and the exact one 6.5 %; the importance sampler's proposals, fitted
to the tempered posterior, spread into it.
"""

from __future__ import annotations

import dataclasses
import logging
import time
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from smcbayes.config import PosteriorSpec
from smcbayes.config.settings import default_of
from smcbayes.errors import SmcBayesWarning
from smcbayes.posterior.correct import CorrectionSettings, ImportanceSample, correct, weighted_quantile
from smcbayes.posterior.curve_spread import curve_spread
from smcbayes.posterior.curves import CurveEmulator, log_posterior
from smcbayes.posterior.sampler import Chains, SamplerSettings, ensemble_size, run_ensemble
from smcbayes.posterior.threads import thread_map

logger = logging.getLogger(__name__)

Array = NDArray[np.float64]

EXPECTED_LOSS = True
"""The emulated likelihood (of the rounds, the reported posterior, the rounds' errors and the
emulator check) is that of the expected loss: the mean curves' loss plus the emulator's
(calibrated) variance of the squared error
(:meth:`~smcbayes.posterior.curves.CurveEmulator.loss`).  The loss is convex in the curves,
so the mean curves' loss is the lower one wherever the emulator is unsure: on the accuracy
benchmark's two cases the mean curves' posterior put too much mass where tau* is large (a
flat arm: a yield stress above every flow stress), and posteriors called reliable missed
tau*'s 95 % quantile by up to 0.13 of its range.  Before the variances were calibrated,
the expected loss lowered the likelihood too much where the emulator has few points
(after 140-380 runs its posterior was further from the exact one than the mean curves')."""

CHAIN_STEPS = 3000
"""Most emcee steps of the final chains, which only start the importance sampling (of the
emulator, or the forward model's correction): the reported posterior is the weighted one."""

WARM_CHAIN_STEPS = 1000
"""Most emcee steps of the final chains when their walkers start at draws of a close
emulated posterior (a confirmation's, from the last round's sample): they need no way in
from the best training point, and they only start the importance sampling, whose first
proposal also takes those draws."""

ROUND_ESS = 200
"""Least importance ESS of an active-learning round's sample whose quantile shift can
validate the round: with a few heavy draws both weightings of the shift sit on the same
points and the posterior would look still however it moved.  Every importance sample of the
emulator counts as settled only from twice this ESS."""

EMULATOR_DRAWS = 160000
"""Most proposal draws of the importance sampling of the reported emulated posterior
(emulator evaluations, no forward run); as many once more, from what it found, if its
weights have not settled at the correction's targets."""

FINAL_ESS = 8000.0
"""Importance ESS the sample of the reported emulated posterior aims at (it counts as
settled at the correction's lower target).  At the correction's 2,000 the adaptive
proposals still under-cover a flat arm, and the weights do not show it: on one emulator of
the accuracy benchmark's second case, eight seeds put tau*'s 95 % quantile at 0.55-0.68
(the exact posterior's is 0.70) with k-hat 0.15-0.32; at 8,000 six seeds put it at
0.65-0.68."""

FINAL_ITERATION = 12000
"""Proposal draws per iteration of the reported emulated posterior's sample: fewer, larger
iterations than the rounds' samples, as each iteration evaluates its new proposal at every
draw so far (for draws of a given size, the time grows with the square of the iterations).
On an emulator of 700 points of the measured thesis trials the sample reached its aim in
11.0 s at 12,000 draws an iteration and 15.2 s at 6,000 (three seeds each; ESS 8,540 and
8,170)."""

START_ROWS = 4000
"""Most draws the first proposal of an importance sampling of the emulator is fitted to."""

EMULATOR_BATCH = 2000
"""Rows of one emulator call of an importance sample (each a task of the emulator's threads,
:func:`batched`).  Each call builds ``(rows, features)`` curves, 29 MB at 2,000 rows of
the measured thesis trials' 1,818 features: 16,000 rows of an emulator of 700 points took
0.71 s in batches of 2,000 and 0.87 s in batches of 4,000, whose arrays are twice as
large."""

EMULATOR_ITERATION = 4000
"""Proposal draws per iteration of the importance sampling of the emulator: each
iteration refits the mixture proposal and evaluates it at every draw so far, which costs
more than the emulator at the correction's 500 draws an iteration.  On an emulator of 700
points of the measured thesis trials, a round's 20,000 draws reached an ESS of 1,140 in
1.5 s at 4,000 draws an iteration and 1,080 in 2.1 s at 2,000 (six seeds each)."""


@dataclass
class CurveEmulation:
    """The sampled curve emulator, as the stage's outputs read an emulator.

    Attributes:
        emulator: the fitted curve emulator.
        n_eff: effective points of the likelihood.
    """

    emulator: CurveEmulator
    n_eff: float
    functions: int = 0
    components: int = 1

    def log_loss(self, u: Array) -> Array:
        """Emulated log loss ``(P,)`` at unit-cube points ``(P, d)`` (the expected loss, as sampled)."""
        return np.log(np.maximum(self.emulator.loss(np.atleast_2d(u), variance=EXPECTED_LOSS), 1e-300))


@dataclass
class FinalPosterior:
    """The curve emulator's reported posterior, before the stage's outputs.

    Attributes:
        chains: the emcee chains that started the importance sampling.
        sample: the mean's importance sample of the emulated posterior (unit cube).
        spread: how far the emulator's sample functions move it
            (:func:`~smcbayes.posterior.curve_spread.function_spread`); ``None`` when not
            measured.
        pooled: ``sample`` pooled with the functions' posteriors; ``None`` when not measured.
        seconds: wall time of the ``sampling`` (chains and importance sample) and the ``spread``.
    """

    chains: list[Chains]
    sample: ImportanceSample
    spread: dict[str, Any] | None
    pooled: ImportanceSample | None
    seconds: dict[str, float]

    @property
    def max_shift(self) -> float:
        """The spread's largest quantile move (share of the unit cube); infinite when not measured."""
        return float(self.spread["max_quantile_shift"]) if self.spread else float("inf")


def sample_chains(emulator: CurveEmulator, n_eff: float, rng: np.random.Generator, centre: Array,
                  steps: int = CHAIN_STEPS, walkers: int = 32, label: str = "",
                  start: Array | None = None, log_prob: Callable[[Array], Array] | None = None) -> Chains:
    """emcee chains (differential evolution, from ``centre`` ``(d,)``, or from the walkers'
    distinct positions ``start`` ``(W, d)``, W the ensemble's walkers,
    :func:`~smcbayes.posterior.sampler.ensemble_size`) of the emulated posterior (of the
    expected loss, :data:`EXPECTED_LOSS`), or of the log density ``log_prob``
    ``(P, d) -> (P,)`` on the unit cube when given."""
    settings = SamplerSettings(walkers=walkers, max_steps=steps, min_steps=min(500, steps), moves="de")
    target = log_posterior(emulator, n_eff, variance=EXPECTED_LOSS) if log_prob is None else log_prob
    return run_ensemble(target, emulator.x.shape[1], settings, rng, centre, label, start)


def curve_chains(emulation: CurveEmulation, settings: PosteriorSpec, rng: np.random.Generator,
                 start: Array | None = None) -> list[Chains]:
    """The emcee chains (one ensemble) of the emulated posterior: from the best training
    point, at most :data:`CHAIN_STEPS` steps, or, given draws ``start`` ``(S, d)`` of an
    emulated posterior close to this one with at least as many distinct rows as there are
    walkers, from as many of those rows, at most :data:`WARM_CHAIN_STEPS` steps."""
    emulator = emulation.emulator
    d = emulator.x.shape[1]
    centre = emulator.x[np.argmin(emulator.features.loss(emulator.y))]
    walkers = ensemble_size(settings.walkers, d)
    # resampled draws repeat their heavy points, and two walkers may not share one
    rows = None if start is None else np.unique(np.asarray(start, dtype=float).reshape(-1, d), axis=0)
    at = None if rows is None or len(rows) < walkers else rows[rng.choice(len(rows), walkers, replace=False)]
    if rows is not None and at is None:
        logger.info("curve emulator: %d distinct draws to start %d walkers at; the chains start at the "
                    "best training point", len(rows), walkers)
    cap = CHAIN_STEPS if at is None else WARM_CHAIN_STEPS
    # the default steps serve the log-loss emulator's chains: only a choice of the user's is worth a word
    if settings.steps > cap and settings.steps != default_of(PosteriorSpec, "steps"):
        logger.info("curve emulator: %d emcee steps, not %d: the chains only start the importance sampling",
                    cap, settings.steps)
    return [sample_chains(emulator, emulation.n_eff, rng, centre, min(settings.steps, cap), walkers,
                          label=" (curve emulator)", start=at)]


def batched(log_prob: Callable[[Array], Array]) -> Callable[[Array], Array]:
    """``log_prob`` ``(P, d) -> (P,)`` evaluated in batches of :data:`EMULATOR_BATCH` rows
    shared out over the emulator's threads (:func:`~smcbayes.posterior.threads.thread_map`):
    each call builds ``(rows, points)`` correlations and ``(rows, features)`` curves."""
    def evaluate(u: Array) -> Array:
        parts = thread_map(log_prob, [u[i:i + EMULATOR_BATCH] for i in range(0, len(u), EMULATOR_BATCH)])
        return np.concatenate(parts) if parts else np.empty(0)

    return evaluate


def emulator_sample(emulator: CurveEmulator, n_eff: float, start: Array, spec: CorrectionSettings,
                    draws: int, rng: np.random.Generator, aim: float = 0.0,
                    per_iteration: int | None = None) -> ImportanceSample:
    """The emulated posterior (of the expected loss) by adaptive importance sampling from the
    draws ``start`` ``(S, d)``: the correction's algorithm with the emulator as its target,
    at most ``draws`` emulator evaluations in iterations of ``per_iteration`` (default
    :data:`EMULATOR_ITERATION`, read at the call) and no forward run.  It is settled at the
    correction's k-hat target and an ESS of at least the correction's target and
    ``2 * ROUND_ESS``, and once settled draws on to an ESS of ``aim``."""
    per_iteration = EMULATOR_ITERATION if per_iteration is None else per_iteration
    # an iteration's draws reach the target at once, which cuts them into EMULATOR_BATCH rows
    run = spec.model_copy(update={"draws": draws, "batch": max(draws, 1), "per_iteration": per_iteration,
                                  "ess_target": max(spec.ess_target, 2 * ROUND_ESS)})
    if len(start) > START_ROWS:  # the first proposal's mixture fit needs no more
        start = start[rng.choice(len(start), START_ROWS, replace=False)]
    with warnings.catch_warnings():
        # the correction's own warnings name its forward-model options; the stage's
        # reliability reasons say what an unsettled sample of the emulator means
        warnings.simplefilter("ignore", SmcBayesWarning)
        sample = correct(batched(log_posterior(emulator, n_eff, variance=EXPECTED_LOSS)), start, run, rng,
                         label="importance sampling of the emulator", runs="emulator evaluations", aim=aim)
    return dataclasses.replace(sample, target="emulator", warnings=[])


def sample_emulator(emulator: CurveEmulator, n_eff: float, start: Array, spec: CorrectionSettings,
                    rng: np.random.Generator) -> ImportanceSample:
    """The emulated posterior (of the expected loss) by adaptive importance sampling from
    the draws ``start`` ``(S, d)``, aiming at an ESS of :data:`FINAL_ESS`: at most
    :data:`EMULATOR_DRAWS` emulator evaluations, as many once more when the weights have not
    settled at the correction's targets; no forward run."""
    def draw(rows: Array) -> ImportanceSample:
        return emulator_sample(emulator, n_eff, rows, spec, EMULATOR_DRAWS, rng, FINAL_ESS, FINAL_ITERATION)

    sample = draw(start)
    if not sample.settled:
        logger.info("the emulator's importance sample has not settled (ESS %.0f, k-hat %.2f): "
                    "drawing %d more", sample.ess, sample.k_hat, EMULATOR_DRAWS)
        sample = draw(np.vstack([start, sample.resample(len(start), rng)]))
    return sample


def importance_sample(emulation: CurveEmulation, chains: list[Chains], settings: PosteriorSpec,
                      rng: np.random.Generator, extra: Array | None = None) -> ImportanceSample:
    """The reported emulated posterior: :func:`sample_emulator` from the emcee draws and
    the draws ``extra`` ``(S, d)``, if any."""
    d = emulation.emulator.x.shape[1]
    start = np.concatenate([c.samples.reshape(-1, d) for c in chains]
                           + ([] if extra is None else [np.asarray(extra, dtype=float)]))
    return sample_emulator(emulation.emulator, emulation.n_eff, start, settings.correction, rng)


def final_posterior(emulation: CurveEmulation, settings: PosteriorSpec, names: Sequence[str],
                    rng: np.random.Generator, spread: bool = True,
                    start: Array | None = None) -> FinalPosterior:
    """The reported posterior of the curve emulator: the emcee chains (from draws ``start``
    ``(S, d)`` of a close emulated posterior, if given, :func:`curve_chains`), the importance
    sample from their draws and ``start``'s and, with ``spread``, the sample functions'
    spread around it and the pooled sample
    (:func:`~smcbayes.posterior.curve_spread.curve_spread`; ``names`` are the free
    parameters')."""
    t0 = time.perf_counter()
    chains = curve_chains(emulation, settings, rng, start)
    sample = importance_sample(emulation, chains, settings, rng, start)
    t1 = time.perf_counter()
    measured, pooled = (curve_spread(emulation.emulator, emulation.n_eff, sample, names, rng) if spread
                        else (None, None))
    return FinalPosterior(chains, sample, measured, pooled,
                          {"sampling": t1 - t0, "spread": time.perf_counter() - t1})


def quantile_shift(sample: ImportanceSample, before: Callable[[Array], Array]) -> float:
    """How far the emulated posterior moved since an earlier emulator (the last round's, or,
    for the drift, the one before the validating rounds): the largest difference
    (share of the unit cube) between a 5/50/95 % quantile of ``sample`` and the same
    quantile under the earlier emulator's log posterior ``before``, both weighted over the
    same draws (the earlier posterior by the ratio of the two densities), so that the
    sampling noise of the draws cancels and what remains is the emulator's change."""
    w = sample.weights
    keep = w > 0
    u, w = sample.unit[keep], w[keep]
    old = batched(before)(u)
    log_ratio = old - sample.log_target[keep]
    finite = np.isfinite(log_ratio)
    if not np.any(finite):
        return float("inf")
    w_before = w * np.exp(np.where(finite, log_ratio - np.max(log_ratio[finite]), -np.inf))
    q = [0.05, 0.5, 0.95]
    return float(max(np.max(np.abs(weighted_quantile(u[:, j], w, q)
                                   - weighted_quantile(u[:, j], w_before / w_before.sum(), q)))
                     for j in range(u.shape[1])))
