"""Where a round of the curve emulator's active learning runs its posterior draws, and how
their errors are weighted back to the posterior's shares.

The draws come from the pooled posterior (the emulated posterior pooled with those of GP
sample functions, :mod:`smcbayes.posterior.curve_spread`), leaning to where the functions
disagree: there the next forward runs settle the posterior.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from smcbayes.posterior.curve_spread import FunctionPosteriors

Array = NDArray[np.float64]

TARGETED = 0.5
"""Share of the rounds' posterior draws' proposal that leans to where the sample
functions disagree (:func:`targeted`)."""

MOST_DRAWS = 100
"""Most draws per wanted distinct point of a round's posterior draws (:func:`draws`): a
posterior whose weight rests on a few points, the others' weights tiny, gives fewer runs,
not an endless loop."""


def targeted(posteriors: FunctionPosteriors, count: int, rng: np.random.Generator
             ) -> tuple[NDArray[np.int_], Array, dict[str, float]]:
    """Up to ``count`` distinct support points drawn from the pooled posterior p, each
    point's weight raised by its sample functions' disagreement s (sd of the log-likelihood,
    nats): independent draws (:func:`draws`) from the mixture
    ``q = (1 - TARGETED) p + TARGETED p s / E_p[s]``.

    Density times the emulator's uncertainty is the acquisition of Acerbi (2018,
    "Variational Bayesian Monte Carlo", NeurIPS) and of Kandasamy, Schneider & Poczos
    (2017, Artificial Intelligence 243); mixed with the density itself (defensive
    importance sampling: Hesterberg 1995, Technometrics 37, 185), so that the rounds'
    errors still estimate the error at posterior draws with bounded weights.

    Returns:
        The points' indices into the support ``(points,)``; the weights ``(points,)`` that
        turn the errors at them into the posterior's mean error (how often each was drawn
        times its importance weight ``p / q``, at most ``1 / (1 - TARGETED)``); and what
        ``refine.jsonl`` keeps of the aiming: the points, the draws, the points' ESS under
        those weights and the functions' mean disagreement under p (nats).
    """
    p = posteriors.pooled()
    s = posteriors.disagreement()
    # a function whose loss is not finite at a point has no spread there to measure
    s = np.where(np.isfinite(s), s, 0.0)
    up = lift(p, s)
    chosen, times = draws(p * up, count, rng)
    weight = times / up[chosen]
    aim = {"posterior_points": len(chosen), "draws": int(times.sum()),
           "error_weight_ess": float(weight.sum() ** 2 / np.sum(weight ** 2)),
           "mean_disagreement_nats": float(np.sum(p * s))}
    return chosen, weight, aim


def lift(p: Array, s: Array) -> Array:
    """The ratio ``q / p`` ``(P,)`` of :func:`targeted`'s proposal to the posterior weights
    ``p`` ``(P,)`` (summing to one), from the disagreement ``s`` ``(P,)``; one everywhere
    where the functions agree everywhere."""
    mean = float(np.sum(p * s))
    if not (mean > 0.0 and np.isfinite(mean)):
        return np.ones_like(p)
    return (1.0 - TARGETED) + TARGETED * s / mean


def draws(weights: Array, count: int, rng: np.random.Generator) -> tuple[NDArray[np.int_], NDArray[np.int_]]:
    """Independent draws by ``weights`` ``(N,)`` until ``count`` (at least one) distinct
    indices turned up (fewer when fewer carry weight, or after :data:`MOST_DRAWS` times
    ``count`` draws): the distinct indices and how often each was drawn.

    The draws are independent and whether to stop depends only on those made so far, so
    the mean over the draws (each point's value counted as often as it was drawn) is a
    consistent estimate of the mean under ``weights``: the draw that stops them falls on a
    new point and over-weights it by that one draw, a bias of order one over the number
    drawn.  The distinct points of a weighted choice without replacement count each point
    once, however heavy: a point holding 90 % of the weight gets a 20th of it among 20.
    """
    if count < 1:
        raise ValueError(f"draws needs a count of at least one, not {count}")
    p = weights / weights.sum()
    target = min(count, int(np.count_nonzero(p > 0)))
    drawn = np.empty(0, dtype=np.int_)
    while len(drawn) < MOST_DRAWS * count:
        drawn = np.concatenate([drawn, rng.choice(len(p), 4 * count, p=p)])
        _, first = np.unique(drawn, return_index=True)
        if len(first) >= target:
            # the draws after the one that completed the set were not needed
            drawn = drawn[:np.sort(first)[target - 1] + 1]
            break
    return np.unique(drawn, return_counts=True)
