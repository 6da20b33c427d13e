"""How far the curve emulator's own uncertainty moves its posterior, and the pooled result.

The curve emulator's reported posterior is that of its expected loss (the mean curves' loss
plus the emulator's variance of it), sampled by importance; below, "the mean's posterior" is
that one, the emulator's own without a sample function.
A GP sample function of the emulator's outputs (principal-component scores, switch times,
end heights) gives other curves, another loss and so another posterior.  As for the log-loss
emulator (:mod:`smcbayes.posterior.spread`: Kandasamy, Schneider & Poczos 2017, Artificial
Intelligence 243; Acerbi 2018, NeurIPS), the functions' posteriors measure whether the
forward runs spent on the emulator determine the posterior, and pooled with the mean's they
carry the emulator's uncertainty into the reported result.

The sample functions are drawn jointly at a support of points taken from the mean's
importance sample with probabilities proportional to the square root of their weights
(wider than the posterior, so that a function may shift mass into its tails), and each
function's posterior is the support reweighted by its likelihood ratio to the mean's:
``w_j(x) ~ c(x) w(x)^(1/2) exp(l_j(x) - l(x))`` for a point drawn ``c(x)`` times.  The
emulator's outputs share one correlation and differ in scale, so one factorisation of the
support's posterior correlation serves every output and function.  The spread is, for each
parameter and 5/50/95 % quantile, the move from the mean's posterior that one function in
ten exceeds (:data:`SHIFT_LEVEL`), largest over them: a level of the functions'
distribution, where the largest move of a few functions grows with their number and varies
much from draw to draw.  The reported posterior's spread pools the functions of several
supports (:data:`SPREAD_SUPPORTS`), each measured against the mean's posterior on its own
support.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.linalg import solve_triangular
from scipy.special import logsumexp

from smcbayes.errors import SurrogateError
from smcbayes.posterior.correct import ImportanceSample
from smcbayes.posterior.curves import CurveEmulator, matern52
from smcbayes.posterior.spread import QUANTILES
from smcbayes.posterior.threads import thread_map
from smcbayes.posterior.weights import ess_of, weighted_quantile

Array = NDArray[np.float64]

CURVE_FUNCTIONS = 32
"""Sample functions of the curve emulator on each support (each costs one evaluation of the
support's curves, about 0.1 s).  On the emulators of 16 rounds of the measured thesis trials, two
independent draws of the largest move of four functions differed by 0.09 of a parameter's
range on average (up to 0.38); two of the move that one of 32 in ten exceeds, by 0.03 (up
to 0.11)."""

SHIFT_LEVEL = 0.9
"""Share of the sample functions whose move of a quantile the spread bounds: the spread is
the move that one function in ten exceeds."""

SPREAD_SUPPORTS = 12
"""Supports of the reported posterior's spread, each with its own :data:`CURVE_FUNCTIONS`
functions (the rounds of the active learning draw one).  Where a posterior's tail rests on
a few heavy points of its sample, whether one function in ten moves a quantile there flips
from draw to draw, and the reading decides the verdict against
:data:`~smcbayes.posterior.spread.SPREAD_MAX`.  On the final emulator of one run on the
measured thesis trials, eight draws of the spread on one support gave 0.065-0.225 (sd
0.017 and 0.047 over two importance samples), on four 0.075-0.134 (sd 0.020 and 0.014);
on the final emulator of another run, whose stage had read 0.110 on four supports and
called it unreliable, ten further draws on the same importance sample gave 0.059-0.096 on
four (sd 0.011) and 0.062-0.081 on twelve (sd 0.007).  A support costs 1.5-3 s on these
emulators."""

SPREAD_RESAMPLES = 200
"""Resamples of the supports (with replacement) whose spreads give the spread's standard
error (Efron & Tibshirani 1993, "An Introduction to the Bootstrap", ch. 6): the supports,
each a fresh draw of points and functions, are the reading's independent units."""

SPREAD_RESAMPLE_SEED = 20240607
"""Seed of the supports' resampling: its own generator, so that the standard error leaves
the stage's random stream, and with it every later draw, as it was."""

SUPPORT_POINTS = 1500
"""Draws of the support (with repeats) on which the sample functions are drawn jointly."""

SPREAD_MIN_ESS = 50
"""Least importance ESS of a sample function's posterior on the support for the spread it
shows to be measured (below it, the function's posterior lies mostly where the mean's
sample has no points)."""

JITTER = 1e-8
"""Added to the support's posterior correlation before its factorisation (unit variance)."""


def joint_outputs(emulator: CurveEmulator, x: Array, count: int, rng: np.random.Generator) -> Array:
    """``count`` joint draws ``(count, P, J + S)`` of the emulator's outputs at the distinct
    points ``x`` ``(P, d)`` (unit cube): the GP mean plus the posterior correlation's factor
    times standard normals, scaled per output (the latent function: the nugget is left out)."""
    corr = emulator.corr
    r = matern52(x, emulator.x, corr.lengthscales)
    mean = r @ emulator.alpha + emulator._h(x) @ emulator.trend
    v = solve_triangular(corr.chol, r.T, lower=True)
    cov = matern52(x, None, corr.lengthscales) - v.T @ v
    try:
        factor = np.linalg.cholesky(cov + JITTER * np.eye(len(x)))
    except np.linalg.LinAlgError:  # rounding left the correlation indefinite: clip its spectrum
        val, vec = np.linalg.eigh(cov)
        factor = vec * np.sqrt(np.maximum(val, 0.0))
    z = rng.standard_normal((count, len(x), mean.shape[1]))
    # one product per function, on the emulator's threads (each what the stacked product computes)
    draws = np.array(thread_map(lambda zk: factor @ zk, list(z))).reshape(z.shape)
    return mean[None] + draws * np.sqrt(emulator.output_variance)[None, None, :]


def _log_lik(emulator: CurveEmulator, outputs: Array, n_eff: float) -> Array:
    """-(N_eff / 2) log L ``(P,)`` of emulated outputs ``(P, J + S)``."""
    loss = emulator.features.loss(emulator.curves(outputs))
    return -0.5 * n_eff * np.log(np.maximum(loss, 1e-300))


def _support(sample: ImportanceSample, rng: np.random.Generator) -> tuple[NDArray[np.intp], Array]:
    """Distinct rows of ``sample`` drawn with probabilities ~ sqrt(weight), and the log of
    each one's importance weight for the mean's posterior ``(P,)`` (count * sqrt(weight))."""
    half = np.where(np.isfinite(sample.log_weight), 0.5 * sample.log_weight, -np.inf)
    if not np.isfinite(half).any():
        raise SurrogateError("the emulated posterior's importance sample has no point of positive weight")
    p = np.exp(half - logsumexp(half))
    rows, counts = np.unique(rng.choice(len(p), size=SUPPORT_POINTS, p=p), return_counts=True)
    return rows, np.log(counts) + half[rows]


def _normalised(log_w: Array) -> Array:
    """Log weights ``(P,)`` normalised to sum to one; all -inf where none is finite."""
    finite = np.isfinite(log_w)
    if not finite.any():
        return np.full_like(log_w, -np.inf)
    return np.where(finite, log_w - logsumexp(log_w[finite]), -np.inf)


def _quantiles(unit: Array, w: Array) -> Array:
    """5/50/95 % quantiles ``(3, d)`` of the points ``unit`` ``(P, d)`` under the weights ``w`` ``(P,)``."""
    w = w / np.sum(w)
    return np.stack([weighted_quantile(unit[:, k], w, list(QUANTILES)) for k in range(unit.shape[1])], axis=1)


def _function_shift(x: Array, ref: Array, log_w: Array) -> Array:
    """|Quantile differences| ``(3, d)`` between the weighted support ``x`` ``(P, d)``
    under the log weights ``log_w`` ``(P,)`` and the mean's quantiles ``ref`` ``(3, d)``;
    the whole range (1) where the function's likelihood vanishes everywhere on the support."""
    if not np.isfinite(log_w).any():
        return np.ones_like(ref)
    return np.abs(_quantiles(x, np.exp(log_w)) - ref)


def quantile_moves(x: Array, log_mean: Array, log_functions: Array) -> tuple[Array, Array]:
    """The mean's 5/50/95 % quantiles ``(3, d)`` on the support ``x`` ``(P, d)`` under its
    normalised log weights ``log_mean`` ``(P,)``, and each function's move of them ``(F, 3, d)``
    (log weights ``log_functions`` ``(F, P)``; the whole range, 1, for a function whose
    likelihood vanishes everywhere on the support)."""
    ref = _quantiles(x, np.exp(log_mean))
    return ref, np.array([_function_shift(x, ref, lw) for lw in log_functions])


@dataclasses.dataclass
class FunctionPosteriors:
    """GP sample functions' posteriors on a support of an importance sample of the mean's.

    Attributes:
        rows: the support's indices into the sample ``(P,)`` (distinct).
        log_mean: the mean's normalised log weights on the support ``(P,)``.
        log_functions: each function's normalised log weights ``(F, P)``.
        log_lik: each function's log-likelihood ``(F, P)`` (nats).
    """

    rows: NDArray[np.intp]
    log_mean: Array
    log_functions: Array
    log_lik: Array

    def pooled(self) -> Array:
        """The pooled posterior's weights on the support ``(P,)``: the mean and each function
        an equal share (summing to one)."""
        w = (np.exp(self.log_mean) + np.sum(np.exp(self.log_functions), axis=0)) / (len(self.log_lik) + 1.0)
        return w / w.sum()

    def disagreement(self) -> Array:
        """Standard deviation over the functions of the log-likelihood at each support point
        ``(P,)`` (nats): where more forward runs would move the functions' posteriors most."""
        return np.std(self.log_lik, axis=0)


def function_posteriors(emulator: CurveEmulator, n_eff: float, sample: ImportanceSample,
                        rng: np.random.Generator, functions: int = CURVE_FUNCTIONS) -> FunctionPosteriors:
    """``functions`` sample functions' posteriors on a support drawn from ``sample`` (the
    mean's importance sample: unit cube ``(N, d)``, its ``log_target`` the emulated log
    posterior)."""
    rows, log_w0 = _support(sample, rng)
    x, base = sample.unit[rows], sample.log_target[rows]
    outputs = joint_outputs(emulator, x, functions, rng)
    lik = np.array(thread_map(lambda out: _log_lik(emulator, out, n_eff), outputs))
    log_ws = np.array([_normalised(log_w0 + lj - base) for lj in lik])
    return FunctionPosteriors(rows, _normalised(log_w0), log_ws, lik)


def curve_spread(emulator: CurveEmulator, n_eff: float, sample: ImportanceSample, names: Sequence[str],
                 rng: np.random.Generator, functions: int = CURVE_FUNCTIONS, supports: int = SPREAD_SUPPORTS,
                 ) -> tuple[dict[str, Any], ImportanceSample]:
    """The spread of ``functions`` sample functions' posteriors on each of ``supports``
    supports around the mean's, and the mean's importance sample pooled with them (each
    posterior an equal share).

    Args:
        emulator: the curve emulator whose posterior ``sample`` weights.
        n_eff: effective points of the likelihood.
        sample: the mean's importance sample (unit cube, ``(N, d)``; its ``log_target``
            the emulated log posterior).
        names: the free parameters' names, ``d`` of them.
        rng: draws the support and the functions.
        functions: sample functions per support.
        supports: supports, each drawn anew.

    Returns:
        :func:`spread_and_pool` of the functions' posteriors.
    """
    drawn = [function_posteriors(emulator, n_eff, sample, rng, functions) for _ in range(supports)]
    return spread_and_pool(drawn, sample, names)


def spread_and_pool(posteriors: Sequence[FunctionPosteriors], sample: ImportanceSample, names: Sequence[str],
                    ) -> tuple[dict[str, Any], ImportanceSample]:
    """The spread of the functions' ``posteriors`` (one per support, :func:`function_spread`)
    with ``pooled_shift``, the largest move of a quantile from the mean's posterior to the
    pooled one (both on the whole sample), and the pooled sample: the mean's points, each
    weighted by the mean's share plus the functions' shares of it (its ``log_target`` stays
    the mean's)."""
    spread = function_spread(posteriors, sample, names)
    share = 1.0 / (spread["functions"] + 1.0)
    weight = np.exp(sample.log_weight) * share
    for support in posteriors:
        for lw in support.log_functions:
            np.add.at(weight, support.rows, np.exp(lw) * share)
    with np.errstate(divide="ignore"):
        log_weight = np.log(weight / weight.sum())
    # how far the pooling moved the reported posterior from the mean's, on the same points
    # (the functions' shares sit on the support, so its subsampling noise is included)
    spread["pooled_shift"] = float(np.max(np.abs(_quantiles(sample.unit, np.exp(log_weight))
                                                 - _quantiles(sample.unit, np.exp(sample.log_weight)))))
    return spread, dataclasses.replace(sample, log_weight=log_weight, ess=ess_of(log_weight))


def _level_shifts(moves: Array) -> Array:
    """Per parameter ``(d,)``, the largest over its 5/50/95 % quantiles of the move that
    :data:`SHIFT_LEVEL` of the functions' ``moves`` ``(F, 3, d)`` stay within (shares of
    the parameter's range)."""
    return np.max(np.quantile(moves, SHIFT_LEVEL, axis=0), axis=0)


def spread_standard_error(moves: Sequence[Array]) -> float | None:
    """Bootstrap standard error of the spread (the largest of :func:`_level_shifts`, a share
    of a parameter's range) over the supports, given each support's functions' moves
    ``(F, 3, d)``: the standard deviation of the spreads of :data:`SPREAD_RESAMPLES`
    resamples of the supports with replacement; ``None`` for one support, whose reading
    has nothing to be compared with.  It covers the draw of the supports only, for the
    emulator and importance sample given."""
    if len(moves) < 2:
        return None
    rng = np.random.default_rng(SPREAD_RESAMPLE_SEED)
    picks = rng.integers(0, len(moves), size=(SPREAD_RESAMPLES, len(moves)))
    spreads = [np.max(_level_shifts(np.concatenate([moves[k] for k in pick]))) for pick in picks]
    return float(np.std(spreads, ddof=1))


def function_spread(posteriors: Sequence[FunctionPosteriors], sample: ImportanceSample,
                    names: Sequence[str]) -> dict[str, Any]:
    """The spread of the functions' ``posteriors`` (one per support) around the mean's
    ``sample``, in the keys :func:`smcbayes.posterior.spread.emulator_spread` records and
    one more: per parameter, the move of a quantile against the mean's posterior on the
    function's own support that one function in ten exceeds (``shift_level``; not net of
    any noise; ``sampling_noise`` is the largest of the supports' own, against the whole
    sample), with each function's ESS on its support, the ``supports`` and their distinct
    points together (``support_points``), and the spread's standard error over the
    supports (``max_quantile_shift_se``, :func:`spread_standard_error`; ``None`` for one),
    which the log-loss emulator's record has not."""
    moves: list[Array] = []
    noise = np.zeros(sample.unit.shape[1])
    whole = _quantiles(sample.unit, np.exp(sample.log_weight))
    for support in posteriors:
        x = sample.unit[support.rows]
        # against the mean's posterior, not the pooled one: the functions' posteriors, each of
        # its own curves' loss, lean together to where the emulator is unsure (there the log of
        # the expected loss exceeds the expected log loss), and that common lean is part of the
        # emulator's uncertainty the spread must show (measured against the pooled posterior, a
        # synthetic posterior 0.18 off in a quantile passed with a spread of 0.086)
        ref, moved = quantile_moves(x, support.log_mean, support.log_functions)
        # on the common support the support's own subsampling cancels (as in the rounds'
        # quantile shift); its noise against the whole sample is reported, not subtracted
        noise = np.maximum(noise, np.max(np.abs(ref - whole), axis=0))
        moves.append(moved)
    shifts = _level_shifts(np.concatenate(moves))
    return {"functions": sum(len(m) for m in moves), "steps": 0, "supports": len(posteriors),
            "support_points": int(len(np.unique(np.concatenate([support.rows for support in posteriors])))),
            "shift_level": SHIFT_LEVEL,
            "max_quantile_shift": float(np.max(shifts)),
            "max_quantile_shift_se": spread_standard_error(moves),
            "per_parameter": {n: float(v) for n, v in zip(names, shifts, strict=True)},
            "sampling_noise": {n: float(v) for n, v in zip(names, noise, strict=True)},
            "function_ess": [ess_of(lw) for support in posteriors for lw in support.log_functions]}
