"""Refinement of the emulator where the posterior lives, and a check of the emulator.

A refinement round (one round of the stage's active learning) evaluates the forward model
at three kinds of points (:func:`round_design`):

* random posterior draws of the current emulator: unbiased test points; the emulator's
  error there, *before* they join the training data, is the round's out-of-sample check
  (:func:`check_values`) and drives the stopping rule of the stage;
* the points where the GP is most unsure and a tempered posterior could be large
  (:func:`log_exp_acquisition`, :func:`acquisition_points`), among the posterior draws and
  uniform draws over the whole prior box, greedily and at least ``min_distance`` apart in
  the unit cube, including regions the current emulated posterior has not reached;
* a Latin hypercube over the box of the bulk of the draws (:func:`local_box`), which
  fills the posterior's region evenly, tails included, where draws are sparse, and random
  draws of the tempered (likelihood to the power 1/4) emulated posterior of one GP sample
  function, which reach along ridges, into flat arms the posterior itself hardly visits and
  into regions the GP mean rates a few nats too low.

Every point of a round, before it joins the training data, also enters a second check
(:func:`relevant_error`): the error where the true or the emulated log-likelihood is near
the best, which catches mass the emulated posterior misses.

The GP is then updated on calibration + refinement data (conditioned on the new points,
its hyperparameters refitted once the data have grown enough).

The check runs the forward model at posterior draws and compares the emulated with the
true log-likelihood, -(N_eff/2) log L, in nats.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

import numpy as np
from numpy.typing import NDArray
from scipy.stats import qmc

Array = NDArray[np.float64]


class Predictor(Protocol):
    """A GP of log(loss): :class:`~smcbayes.surrogate.gp.Surrogate` or its NumPy copy
    :class:`~smcbayes.posterior.emulator.NumpyGP`."""

    def predict(self, x_unit: Array, /) -> tuple[Array, Array]:
        """Posterior mean and standard deviation of log(loss) at ``x_unit`` ``(N, d)``."""
        ...


def acquisition_zeta(d: int) -> float:
    """Tempering exponent zeta of :func:`log_exp_acquisition` in ``d`` dimensions, d^-1.1.

    El Gammal, Schoeneberg, Torrado & Fidler (2023, "Fast and robust Bayesian inference
    using Gaussian processes with GPry", JCAP 10, 021) choose zeta so that it falls with the
    dimension: the posterior's bulk lies about d/2 nats below its peak, and the acquisition
    must still rate it above the far, uncertain landscape.
    """
    return float(max(int(d), 1)) ** -1.1


def log_exp_acquisition(x_unit: Array, surrogate: Predictor, n_eff: float) -> Array:
    """log of the acquisition exp(2 zeta mu(x)) sigma(x) at ``x_unit`` ``(N, d)``, up to a constant.

    mu and sigma are the GP's mean and standard deviation of the log-likelihood
    l(x) = -(N_eff/2) log L(x) (nats): the GP's uncertainty where a tempered posterior,
    exp(2 zeta l), could be large (El Gammal et al. 2023, the GPry acquisition; zeta from
    :func:`acquisition_zeta`).  Unlike the variance of the posterior density,
    exp(2 mu + sigma^2)(exp(sigma^2) - 1) (Kandasamy et al. 2017; Acerbi 2018), which grows
    like exp(2 sigma^2) and so picks the far, uncertain and improbable corners of the box
    once N_eff/2 is large, it grows only linearly with sigma.  Returns ``(N,)``.
    """
    mean, std = surrogate.predict(x_unit)
    a = 0.5 * n_eff
    zeta = acquisition_zeta(np.asarray(x_unit).shape[1])
    return 2.0 * zeta * (-a * mean) + np.log(np.maximum(a * std, 1e-300))


def acquisition_points(draws_unit: Array, surrogate: Predictor, n_eff: float, count: int,
                       rng: np.random.Generator, min_distance: float = 0.03, pool: int = 2000) -> Array:
    """``count`` points of largest :func:`log_exp_acquisition`, spread out.

    Candidates: up to ``pool`` posterior draws and ``pool // 2`` uniform draws over the prior
    box, so that a region the emulated posterior misses but the GP cannot rule out is found.

    Returns:
        Chosen points, ``(<= count, d)``.
    """
    d = draws_unit.shape[1]
    if count <= 0:
        return np.empty((0, d))
    idx = rng.choice(draws_unit.shape[0], size=min(pool, draws_unit.shape[0]), replace=False)
    cand = np.vstack([draws_unit[idx], rng.uniform(size=(pool // 2, d))])
    score = log_exp_acquisition(cand, surrogate, n_eff)
    chosen: list[Array] = []
    for i in np.argsort(-score):
        x = cand[i]
        if all(np.linalg.norm(x - c) >= min_distance for c in chosen):
            chosen.append(x)
        if len(chosen) == count:
            break
    return np.array(chosen) if chosen else np.empty((0, d))


def quantile_shift(previous: Array | None, draws_unit: Array) -> tuple[Array, float]:
    """5/50/95 % quantiles of ``draws_unit`` ``(N, d)`` and their largest change (unit-cube
    coordinates, i.e. shares of the prior range) since ``previous`` ``(3, d)`` (inf without)."""
    q = np.quantile(draws_unit, [0.05, 0.5, 0.95], axis=0)
    return q, float("inf") if previous is None else float(np.max(np.abs(q - previous)))


def local_box(draws_unit: Array, widen: float = 0.5, min_width: float = 0.02) -> tuple[Array, Array]:
    """Box around the bulk of the draws: 1-99 % quantiles widened by ``widen`` of their range."""
    lo, hi = np.quantile(draws_unit, [0.01, 0.99], axis=0)
    pad = np.maximum(widen * (hi - lo), 0.5 * min_width)
    return np.clip(lo - pad, 0.0, 1.0), np.clip(hi + pad, 0.0, 1.0)


def round_design(draws_unit: Array, surrogate: Predictor, count: int,
                 rng: np.random.Generator, n_eff: float, wide_unit: Array | None = None,
                 wide_share: int = 6) -> tuple[Array, int]:
    """Points of one refinement round: a third random posterior draws (first), a
    ``1/wide_share`` random draws of ``wide_unit`` (if given: draws of a tempered posterior,
    or of sample functions' posteriors the GP mean's disagrees with), a sixth a Latin
    hypercube over :func:`local_box`, the rest by :func:`acquisition_points` among the
    posterior draws, the tempered ones and uniform points.

    Returns:
        ``(points (<= count, d), number of leading random draws)``.
    """
    n_rand = count // 3
    n_lhs = count // 6
    rand = draws_unit[rng.choice(draws_unit.shape[0], size=min(n_rand, draws_unit.shape[0]), replace=False)]
    parts = [rand]
    pool = draws_unit
    if wide_unit is not None and wide_unit.shape[0]:
        parts.append(wide_unit[rng.choice(wide_unit.shape[0],
                                          size=min(count // wide_share, wide_unit.shape[0]),
                                          replace=False)])
        pool = np.vstack([draws_unit, wide_unit])
    lo, hi = local_box(draws_unit)
    lhs = qmc.LatinHypercube(d=draws_unit.shape[1], seed=int(rng.integers(2**31 - 1))).random(n_lhs)
    parts.append(lo + lhs * (hi - lo))
    taken = sum(p.shape[0] for p in parts)
    parts.append(acquisition_points(pool, surrogate, n_eff, count - taken, rng))
    return np.vstack(parts), rand.shape[0]


def relevant_error(emulated: Array, true: Array, n_eff: float, window_nats: float = 10.0) -> float:
    """Mean absolute log-likelihood error (nats, no offset removed) of a round's points where
    the true *or* the emulated log-likelihood is within ``window_nats`` of the best of either.

    Unlike :func:`check_values`, whose points are draws of the emulated posterior, this sees
    mass the emulator misses: a point the emulator rates low but the simulator rates high.
    """
    ok = np.isfinite(true) & np.isfinite(emulated)
    if not np.any(ok):
        return float("nan")
    a = 0.5 * n_eff
    ll_true, ll_em = -a * true[ok], -a * emulated[ok]
    top = max(float(np.max(ll_true)), float(np.max(ll_em)))
    near = (ll_true >= top - window_nats) | (ll_em >= top - window_nats)
    return float(np.mean(np.abs(ll_em[near] - ll_true[near])))


def check_values(emulated: Array, true: Array, n_eff: float) -> float:
    """Mean absolute error (nats, common offset removed) of emulated vs true log(loss)."""
    ok = np.isfinite(true) & np.isfinite(emulated)
    if ok.sum() < 2:
        return float("nan")
    err = -0.5 * n_eff * (emulated[ok] - true[ok])
    return float(np.mean(np.abs(err - np.mean(err))))


@dataclass(frozen=True)
class EmulatorCheck:
    """Emulated vs true log-likelihood at posterior draws (nats).

    Attributes:
        points: number of draws checked (successful simulations).
        mean_abs_error, rmse, max_abs_error: of emulated minus true log-likelihood, after
            removing the common offset (only differences of log-likelihood matter).
        correlation: between emulated and true log-likelihood.
    """

    points: int
    mean_abs_error: float
    rmse: float
    max_abs_error: float
    correlation: float

    def as_dict(self) -> dict[str, float]:
        return {k: getattr(self, k) for k in ("points", "mean_abs_error", "rmse",
                                              "max_abs_error", "correlation")}


def check_emulator(draws_unit: Array, emulated_log_loss: Callable[[Array], Array],
                   true_log_loss: Callable[[Array], Array], n_eff: float) -> EmulatorCheck:
    """Compare emulated and true log-likelihood at ``draws_unit`` ``(D, d)``."""
    true = true_log_loss(draws_unit)
    ok = np.isfinite(true)
    em = emulated_log_loss(draws_unit[ok])
    a = 0.5 * n_eff
    err = -a * (em - true[ok])
    err = err - np.mean(err) if err.size else err
    corr = float(np.corrcoef(em, true[ok])[0, 1]) if err.size > 2 and np.std(true[ok]) > 0 else float("nan")
    if not err.size:
        return EmulatorCheck(0, float("nan"), float("nan"), float("nan"), float("nan"))
    return EmulatorCheck(int(ok.sum()), float(np.mean(np.abs(err))), float(np.sqrt(np.mean(err**2))),
                         float(np.max(np.abs(err))), corr)
