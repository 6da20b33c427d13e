"""Refinement of the emulator where the posterior lives, and a check of the emulator.

A refinement round evaluates the forward model at three kinds of points (:func:`round_design`):

* random posterior draws of the current emulator: unbiased test points; the emulator's
  error there, *before* they join the training data, is the round's out-of-sample check
  (:func:`check_values`) and drives the stopping rule of the stage;
* the posterior draws where the GP is most uncertain, greedily and at least
  ``min_distance`` apart in the unit cube (:func:`refine_points`);
* a Latin hypercube over the box of the bulk of the draws (:func:`local_box`), which
  fills the posterior's region evenly, tails included, where draws are sparse.

The GP is then refitted on calibration + refinement data.

The check runs the forward model at posterior draws and compares the emulated with the
true log-likelihood, -(N_eff/2) log L, in nats.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.stats import qmc

from smcbayes.surrogate.gp import Surrogate

Array = NDArray[np.float64]


def refine_points(draws_unit: Array, surrogate: Surrogate, count: int,
                  rng: np.random.Generator, min_distance: float = 0.03,
                  pool: int = 2000) -> Array:
    """``count`` posterior draws with the largest GP standard deviation, spread out.

    Args:
        draws_unit: posterior draws in the unit cube, ``(N, d)``.
        count: number of points wanted.

    Returns:
        Chosen points, ``(<= count, d)``.
    """
    if count <= 0 or draws_unit.shape[0] == 0:
        return np.empty((0, draws_unit.shape[1]))
    idx = rng.choice(draws_unit.shape[0], size=min(pool, draws_unit.shape[0]), replace=False)
    cand = draws_unit[idx]
    _, std = surrogate.predict(cand)
    chosen: list[Array] = []
    for i in np.argsort(-std):
        x = cand[i]
        if all(np.linalg.norm(x - c) >= min_distance for c in chosen):
            chosen.append(x)
        if len(chosen) == count:
            break
    return np.array(chosen)


def local_box(draws_unit: Array, widen: float = 0.5, min_width: float = 0.02) -> tuple[Array, Array]:
    """Box around the bulk of the draws: 1-99 % quantiles widened by ``widen`` of their range."""
    lo, hi = np.quantile(draws_unit, [0.01, 0.99], axis=0)
    pad = np.maximum(widen * (hi - lo), 0.5 * min_width)
    return np.clip(lo - pad, 0.0, 1.0), np.clip(hi + pad, 0.0, 1.0)


def round_design(draws_unit: Array, surrogate: Surrogate, count: int,
                 rng: np.random.Generator) -> tuple[Array, int]:
    """Points of one refinement round: a third random posterior draws (first), a third a
    Latin hypercube over :func:`local_box`, the rest the most uncertain draws.

    Returns:
        ``(points (<= count, d), number of leading random draws)``.
    """
    n_rand = count // 3
    n_lhs = count // 3
    rand = draws_unit[rng.choice(draws_unit.shape[0], size=min(n_rand, draws_unit.shape[0]), replace=False)]
    lo, hi = local_box(draws_unit)
    lhs = qmc.LatinHypercube(d=draws_unit.shape[1], seed=int(rng.integers(2**31 - 1))).random(n_lhs)
    picks = refine_points(draws_unit, surrogate, count - rand.shape[0] - n_lhs, rng)
    return np.vstack([rand, lo + lhs * (hi - lo), picks]), rand.shape[0]


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
        return {k: getattr(self, k) for k in ("points", "mean_abs_error", "rmse", "max_abs_error", "correlation")}


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
