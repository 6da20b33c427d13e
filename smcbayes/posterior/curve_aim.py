"""Where a round of the curve emulator's active learning runs its posterior draws, and how
their errors are weighted back to the posterior's shares.

The draws come from the pooled posterior (the emulated posterior pooled with those of GP
sample functions, :mod:`smcbayes.posterior.curve_spread`), leaning to where the functions
disagree and to where their disagreement moves the quantiles the stage's spread judges:
there the next forward runs settle the posterior.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from smcbayes.posterior.curve_spread import SHIFT_LEVEL, FunctionPosteriors, quantile_moves
from smcbayes.posterior.spread import QUANTILES

Array = NDArray[np.float64]

TARGETED = 0.5
"""Share of the rounds' posterior draws' proposal that leans to where the sample
functions disagree (:func:`targeted`)."""

AIMED = 0.5
"""Share of :data:`TARGETED` aimed at the quantiles the sample functions move (:func:`aimed`);
the rest leans to their disagreement alone."""

MOST_DRAWS = 100
"""Most draws per wanted distinct point of a round's posterior draws (:func:`draws`): a
posterior whose weight rests on a few points, the others' weights tiny, gives fewer runs,
not an endless loop."""


def targeted(posteriors: FunctionPosteriors, unit: Array, count: int, rng: np.random.Generator
             ) -> tuple[NDArray[np.int_], Array, dict[str, float]]:
    """Up to ``count`` distinct support points drawn from the pooled posterior p, each
    point's weight raised by its sample functions' disagreement s (sd of the log-likelihood,
    nats) and by how much their disagreement there moves a quantile (:func:`aimed`'s
    weights a): independent draws (:func:`draws`) from the mixture
    ``q = (1 - TARGETED) p + TARGETED ((1 - AIMED) p s / E_p[s] + AIMED a)``.

    Density times the emulator's uncertainty is the acquisition of Acerbi (2018,
    "Variational Bayesian Monte Carlo", NeurIPS) and of Kandasamy, Schneider & Poczos
    (2017, Artificial Intelligence 243); mixed with the density itself (defensive
    importance sampling: Hesterberg 1995, Technometrics 37, 185), so that the rounds'
    errors still estimate the error at posterior draws with bounded weights.

    Args:
        posteriors: the sample functions' posteriors on a support of ``P`` points.
        unit: the support's points ``(P, d)`` (unit cube).
        count: distinct points wanted.
        rng: draws the points.

    Returns:
        The points' indices into the support ``(points,)``; the weights ``(points,)`` that
        turn the errors at them into the posterior's mean error (how often each was drawn
        times its importance weight ``p / q``, at most ``1 / (1 - TARGETED)``); and what
        ``refine.jsonl`` keeps of the aiming: the points, the draws, the points' ESS under
        those weights, the functions' mean disagreement under p (nats), and the shares of
        the draws' proposal and of p beyond the 5 or 95 % quantile the functions move most
        (:func:`aimed`'s tail).
    """
    if unit.shape[0] != len(posteriors.rows):
        raise ValueError(f"the support has {len(posteriors.rows)} points, not {unit.shape[0]}")
    p = posteriors.pooled()
    s = posteriors.disagreement()
    # a function whose loss is not finite at a point has no spread there to measure
    s = np.where(np.isfinite(s), s, 0.0)
    aim_at, tail = aimed(posteriors, unit, p * s)
    up = lift(p, s, aim_at)
    chosen, times = draws(p * up, count, rng)
    weight = times / up[chosen]
    aim = {"posterior_points": len(chosen), "draws": int(times.sum()),
           "error_weight_ess": float(weight.sum() ** 2 / np.sum(weight ** 2)),
           "mean_disagreement_nats": float(np.sum(p * s)),
           "tail_share": float(np.sum((p * up)[tail])), "tail_posterior": float(np.sum(p[tail]))}
    return chosen, weight, aim


def aimed(posteriors: FunctionPosteriors, unit: Array, lean: Array) -> tuple[Array | None, NDArray[np.bool_]]:
    """Where the sample functions' disagreement moves the quantiles: weights ``(P,)`` on
    the support ``unit`` ``(P, d)`` summing to one (``None`` where the functions move no
    quantile or ``lean`` vanishes), and the support points beyond the tail (5 or 95 %)
    quantile they move most ``(P,)`` (for the record; none where the weights are ``None``).

    Reweighting point x by ``exp(e(x))`` and normalising again moves the CDF ``F`` of
    parameter k at q by about ``sum_x p(x) (e(x) - E_p[e]) 1[x_k <= q]``, which is
    ``sum_x p(x) e(x) (1[x_k <= q] - F(q))``, with ``F(q) = alpha`` at the level-alpha
    quantile; the quantile moves by that over the density there (a share of the unit
    cube).  With ``e`` of the size of the functions' disagreement s, each point's part in
    that sum is ``p s |1[x_k <= q] - alpha|``: a weight, not the move itself.  Here
    ``lean`` ``(P,)`` is ``p s`` with p the pooled posterior the round draws from, and q
    the quantiles of the mean's posterior on the support, against which the spread
    measures the moves.  For the 95 % quantile the 5 % of the posterior beyond it count as
    much as the 95 % within it.  The quantiles' weights are mixed in proportion to the
    square of the move that one function in ten makes of each (the spread's level,
    :data:`~smcbayes.posterior.curve_spread.SHIFT_LEVEL`), so that the quantile that
    blocks the stop takes most of the aim (one moved half as far gets a quarter as much):
    runs there settle the quantiles the stage's spread judges, which in a posterior's long
    tails the density-weighted disagreement alone rarely reaches.
    """
    ref, moves = quantile_moves(unit, posteriors.log_mean, posteriors.log_functions)
    level = np.quantile(moves, SHIFT_LEVEL, axis=0)  # (3, d): the spread's move per quantile
    alpha = np.asarray(QUANTILES)
    below = unit.T[None, :, :] <= ref[:, :, None]  # (3, d, P)
    per = np.abs(below - alpha[:, None, None]) * lean
    total = per.sum(axis=2)
    tails = np.where((alpha != 0.5)[:, None], level, -1.0)
    i, k = np.unravel_index(np.argmax(tails), level.shape)
    tail = ~below[i, k] if alpha[i] > 0.5 else below[i, k]
    mix = np.where(total > 0.0, level ** 2, 0.0)
    if not mix.sum() > 0.0:
        return None, np.zeros_like(tail)
    mix = mix / mix.sum()
    return np.einsum("ik,ikp->p", mix, per / np.where(total > 0.0, total, 1.0)[:, :, None]), tail


def lift(p: Array, s: Array, aim: Array | None = None) -> Array:
    """The ratio ``q / p`` ``(P,)`` of :func:`targeted`'s proposal to the posterior weights
    ``p`` ``(P,)`` (summing to one), from the disagreement ``s`` ``(P,)`` and the aimed
    weights ``aim`` ``(P,)`` (summing to one; ``None`` for none, as where no quantile
    moves, and then the lean to the disagreement takes the whole of :data:`TARGETED`); one
    everywhere where the functions agree everywhere (the aimed weights, ``p s`` times a
    factor, vanish then too)."""
    mean = float(np.sum(p * s))
    if not (mean > 0.0 and np.isfinite(mean)):
        return np.ones_like(p)
    lean = s / mean
    if aim is None:
        return (1.0 - TARGETED) + TARGETED * lean
    # the aimed weights carry the factor p, so they vanish where it does
    toward = np.divide(aim, p, out=np.zeros_like(p), where=p > 0.0)
    return (1.0 - TARGETED) + TARGETED * ((1.0 - AIMED) * lean + AIMED * toward)


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
