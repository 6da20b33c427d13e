"""The posterior stage's curve emulator path (``--emulator curves``): active learning of
the force-curve emulator of :mod:`smcbayes.posterior.curves` and the sampling of its
posterior.

Starts from the calibration GP's points (simulated again for their curves, through the
stage's forward cache), then runs rounds of ``batch`` forward runs: half draws of the
emulated posterior pooled with those of GP sample functions
(:mod:`smcbayes.posterior.curve_spread`), leaning to where the functions disagree
(:func:`~smcbayes.posterior.curve_aim.targeted`), half of the tempered one (likelihood^``temper``)
of the optimistic loss (curves one emulator sd closer to the data), which reaches regions
the emulator's mean rates too low because it has no points there.  Each round samples the
emulated posterior by adaptive importance sampling on the emulator (the correction's
algorithm, no forward run): emcee chains started at the best point under-sample a flat arm of the
accuracy benchmark's first case (1.2 % of the mass where the exact posterior has 6.5 %),
and a stopping rule judged on them stopped early and called a posterior reliable that was
0.34 off in a correlation.  Two measures decide when to stop, in each of the last
:data:`VALIDATED_ROUNDS` rounds: the emulator's error at the round's posterior draws,
measured before they join its data (mean absolute, nats of log-likelihood, each draw
weighted back to the posterior's share; at most
``refine_tolerance_nats``), and how far the emulated posterior's quantiles moved
(:func:`quantile_shift`, on common draws, so that the sampling noise cancels; at most
:data:`QUANTILE_SHIFT`); the same rounds' sample functions must also move it by at most
:data:`~smcbayes.posterior.spread.SPREAD_MAX` on average.  A stage whose budget runs out first is
reported unreliable.  ``refine.jsonl`` logs each round.  The reported posterior is that of
the expected loss (:data:`EXPECTED_LOSS`), sampled by importance on the emulator
(:func:`importance_sample`), which the stage pools with its sample functions' posteriors.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from smcbayes.config import PosteriorSpec
from smcbayes.errors import SmcBayesWarning, SurrogateError
from smcbayes.posterior.context import RunContext
from smcbayes.posterior.correct import CorrectionSettings, ImportanceSample, correct, weighted_quantile
from smcbayes.posterior.curve_aim import targeted
from smcbayes.posterior.curve_spread import function_posteriors, function_spread
from smcbayes.posterior.curves import CurveEmulator, CurveFeatures, log_posterior
from smcbayes.posterior.sampler import Chains, SamplerSettings, run_ensemble
from smcbayes.posterior.spread import SPREAD_MAX

logger = logging.getLogger(__name__)

Array = NDArray[np.float64]

BATCH = 40
"""Forward runs per round (one batch through the executor)."""

TEMPER = 0.25
"""Exponent of the exploration's likelihood."""

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

VALIDATED_ROUNDS = 3
"""Rounds in a row whose out-of-sample error is within the tolerance and whose posterior
quantiles moved by at most :data:`QUANTILE_SHIFT`, to stop.  Pooled over the rounds, the
error let the accuracy benchmark's first case stop after 240 active-learning runs at 0.99
nats, its last round 1.3, with a quantile 0.12 of the prior width off."""

QUANTILE_SHIFT = 0.05
"""Largest move of a 5/50/95 % quantile of the emulated posterior between rounds (share of
the unit cube) that a validated round allows."""

ROUND_STEPS = 1000
"""Most emcee steps of a round's tempered sampling."""

CHAIN_STEPS = 3000
"""Most emcee steps of the final chains, which only start the importance sampling (of the
emulator, or the forward model's correction): the reported posterior is the weighted one."""

ROUND_DRAWS = 20000
"""Most proposal draws of a round's importance sample of the emulated posterior (it stops
at the correction's ESS and k-hat targets)."""

ROUND_ESS = 200
"""Least importance ESS of a round's sample whose quantile shift can validate the round:
with a few heavy draws both weightings of :func:`quantile_shift` sit on the same points
and the posterior would look still however it moved."""

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

FINAL_ITERATION = 6000
"""Proposal draws per iteration of the reported emulated posterior's sample: fewer, larger
iterations than the rounds' samples, as each iteration evaluates its new proposal at every
draw so far (for draws of a given size, the time grows with the square of the iterations)."""

START_ROWS = 4000
"""Most draws the first proposal of an importance sampling of the emulator is fitted to."""

EMULATOR_BATCH = 4000
"""Emulator evaluations per call of the importance sampling."""

EMULATOR_ITERATION = 2000
"""Proposal draws per iteration of the importance sampling of the emulator: each
iteration refits the mixture proposal and evaluates it at every draw so far, which costs
more than the emulator at the correction's 500 draws an iteration."""


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


def sample_chains(emulator: CurveEmulator, n_eff: float, rng: np.random.Generator, centre: Array,
                  temper: float = 1.0, steps: int = ROUND_STEPS, walkers: int = 32,
                  variance: bool = EXPECTED_LOSS, label: str = "", optimistic: bool = False) -> Chains:
    """emcee chains (differential evolution, from ``centre`` ``(d,)``) of the emulated
    posterior, tempered by ``temper``, of the loss ``variance`` and ``optimistic`` ask for
    (:meth:`~smcbayes.posterior.curves.CurveEmulator.loss`)."""
    settings = SamplerSettings(walkers=walkers, max_steps=steps, min_steps=min(500, steps), moves="de")
    return run_ensemble(log_posterior(emulator, n_eff, temper, variance, optimistic), emulator.x.shape[1],
                        settings, rng, centre, label)


@dataclass
class _Round:
    """One round's choice of forward runs and the emulated posterior it was drawn from.

    Attributes:
        new: the rows to simulate ``(B, d)``: the first ``posterior`` are draws of the
            emulated posterior pooled with its GP sample functions', leaning to where
            they disagree (:func:`~smcbayes.posterior.curve_aim.targeted`), the rest of
            the tempered optimistic one.
        posterior: how many of ``new`` are posterior draws.
        sample: the round's importance sample of the emulated posterior (the mean's).
        spread: how far its sample functions move its 5/50/95 % quantiles (share of the unit cube).
        error_weight: the weights ``(posterior,)`` of the posterior draws' errors in the
            round's mean error (:func:`~smcbayes.posterior.curve_aim.targeted`).
        aim: what ``refine.jsonl`` keeps of the aiming
            (:func:`~smcbayes.posterior.curve_aim.targeted`).
    """

    new: Array
    posterior: int
    sample: ImportanceSample
    spread: float
    error_weight: Array
    aim: dict[str, float] = field(default_factory=dict)


def _round(emulator: CurveEmulator, n_eff: float, size: int, start: Array, spec: CorrectionSettings,
           rng: np.random.Generator, walkers: int) -> _Round:
    """The next batch of ``size`` rows: half (fewer when the posterior rests on fewer support
    points) drawn from the emulated posterior, sampled by importance (:data:`ROUND_DRAWS`
    emulator evaluations; its first proposal fitted to the earlier round's posterior draws
    ``start`` ``(S, d)`` and tempered draws, a quarter of :data:`START_ROWS` or as many as
    the chains hold; on the first round, whose ``start`` holds only the best training
    points, nearly all tempered; twice as many draws once more when its ESS is below
    :data:`ROUND_ESS`) and pooled with the posteriors of GP sample functions on a support
    of its points, leaning to where they disagree
    (:func:`~smcbayes.posterior.curve_aim.targeted`), the rest from the tempered posterior
    of the optimistic loss (emcee)."""
    d = emulator.x.shape[1]
    centre = emulator.x[np.argmin(emulator.features.loss(emulator.y))]
    # a rejected emcee move repeats its walker's row: simulated twice it would add nothing
    wide = np.unique(sample_chains(emulator, n_eff, rng, centre, TEMPER, ROUND_STEPS, walkers,
                                   optimistic=True).samples.reshape(-1, d), axis=0)
    # after the first round mostly the last round's posterior: the tempered draws alone,
    # twice as wide in every direction, make a first proposal that wastes most of its draws
    # in seven dimensions
    count = min(len(wide), max(START_ROWS // 4, START_ROWS - len(start)))
    share = wide[rng.choice(len(wide), count, replace=False)]
    sample = _emulator_sample(emulator, n_eff, np.vstack([start, share]), spec, ROUND_DRAWS, rng)
    if sample.ess < ROUND_ESS:
        # too few to measure the round's move by: once more, twice as long, from what it found
        found = sample.resample(START_ROWS // 2, rng)
        sample = _emulator_sample(emulator, n_eff, np.vstack([found, share]), spec, 2 * ROUND_DRAWS, rng)
    # the posterior half from the pooled posterior, which the stage reports, leaning to
    # where its sample functions disagree: there the next runs settle it
    posteriors = function_posteriors(emulator, n_eff, sample, rng)
    # functions resting on few points of a round's sample (fewer draws than the stage's
    # final one; an ESS of a few hundred on the measured thesis trials) still count: there
    # some did in every round, and the rounds could never validate; the stage's own check asks it
    spread = function_spread([posteriors], sample, [str(k) for k in range(d)])
    rows, error_weight, aim = targeted(posteriors, max(1, size // 2), rng)
    # fewer distinct posterior points (a posterior on few support points): more exploration
    half = len(rows)
    new = np.vstack([sample.unit[posteriors.rows[rows]],
                     wide[rng.choice(len(wide), size - half, replace=size - half > len(wide))]])
    return _Round(new, half, sample, spread["max_quantile_shift"], error_weight, aim)


def quantile_shift(sample: ImportanceSample, before: Callable[[Array], Array]) -> float:
    """How far the emulated posterior moved since the last round: the largest difference
    (share of the unit cube) between a 5/50/95 % quantile of ``sample`` and the same
    quantile under the earlier emulator's log posterior ``before``, both weighted over the
    same draws (the earlier posterior by the ratio of the two densities), so that the
    sampling noise of the draws cancels and what remains is the emulator's change."""
    w = sample.weights
    keep = w > 0
    u, w = sample.unit[keep], w[keep]
    # in batches: each call builds (rows, points) correlations and (rows, features) curves
    old = np.concatenate([before(u[i:i + EMULATOR_BATCH]) for i in range(0, len(u), EMULATOR_BATCH)])
    log_ratio = old - sample.log_target[keep]
    finite = np.isfinite(log_ratio)
    if not np.any(finite):
        return float("inf")
    w_before = w * np.exp(np.where(finite, log_ratio - np.max(log_ratio[finite]), -np.inf))
    q = [0.05, 0.5, 0.95]
    return float(max(np.max(np.abs(weighted_quantile(u[:, j], w, q)
                                   - weighted_quantile(u[:, j], w_before / w_before.sum(), q)))
                     for j in range(u.shape[1])))


def learn(simulate: Callable[[Array], tuple[Array, NDArray[np.bool_]]], features: CurveFeatures,
          x: Array, y: Array, n_eff: float, budget: int, tolerance_nats: float, rng: np.random.Generator,
          log: Callable[[dict[str, Any]], None] | None = None, walkers: int = 32,
          spec: CorrectionSettings | None = None) -> tuple[CurveEmulator, Array, Array, dict[str, Any]]:
    """Active learning until validated or ``budget`` further runs are spent.

    The emulator is validated when, in each of the last :data:`VALIDATED_ROUNDS` rounds,
    its mean absolute error at the round's fresh posterior draws (weighted back to the
    posterior's shares, :func:`~smcbayes.posterior.curve_aim.targeted`; measured before they
    join its data) is at most ``tolerance_nats`` and the quantiles of the emulated
    posterior moved by at most :data:`QUANTILE_SHIFT`, and the same rounds' sample functions
    moved them by at most :data:`~smcbayes.posterior.spread.SPREAD_MAX` on average (one
    round's, on one support of a thin sample, is too noisy to stop at).

    Args:
        simulate: unit-cube rows ``(P, d)`` -> features ``(P, F)`` and success ``(P,)``.
        features: the feature map.
        x, y: starting rows ``(N, d)`` and their features ``(N, F)`` (successful rows only).
        n_eff: effective points of the likelihood.
        budget: most forward runs of the active learning.
        tolerance_nats: the out-of-sample error that validates a round.
        log: receives one record per round.
        spec: settings of the rounds' importance sampling (the correction's by default).

    Returns:
        The last emulator, its data and the record of the active learning (``evaluations``,
        ``converged``, ``rounds``, ``error_nats`` (the worst of the last rounds' errors),
        ``quantile_shift`` (the last round's), ``last_errors_nats`` and
        ``last_quantile_shifts`` (those of the last :data:`VALIDATED_ROUNDS` rounds; ``None``
        for a round with nothing to compare, or a sample too thin to tell) and
        ``last_spreads`` (those of the last :data:`VALIDATED_ROUNDS` rounds) and
        ``variance_factor`` (the last emulator's calibration of its output variances,
        :meth:`~smcbayes.posterior.curves.CurveEmulator.calibrate`: rows used and range;
        ``None`` when nothing calibrated them)).  The first
        round has no earlier emulator to compare with, so the emulator can be validated
        after ``VALIDATED_ROUNDS + 1`` rounds at the earliest.
    """
    spec = spec or CorrectionSettings()
    spent, rounds = 0, 0
    errors: list[float] = []
    shifts: list[float | None] = []
    spreads: list[float] = []
    recent: list[Array] = []
    before: Callable[[Array], Array] | None = None
    start = x[np.argsort(features.loss(y))[:walkers]]
    emulator = None
    while True:
        t0 = time.perf_counter()
        emulator = _fit(features, x, y, emulator, recent)
        converged = _validated(errors, shifts, tolerance_nats, spreads)
        if converged or spent >= budget:
            break
        step = _round(emulator, n_eff, min(BATCH, budget - spent), start, spec, rng, walkers)
        unclear = before is None or step.sample.ess < ROUND_ESS
        shifts.append(None if unclear else quantile_shift(step.sample, before))
        spreads.append(step.spread)
        before = log_posterior(emulator, n_eff, variance=EXPECTED_LOSS)
        start = step.sample.resample(3 * START_ROWS // 4, rng)
        t1 = time.perf_counter()
        y_new, ok = simulate(step.new)
        spent, rounds = spent + len(step.new), rounds + 1
        errors.append(_fresh_error(emulator, n_eff, step, y_new, ok))
        recent.append(step.new[ok])
        x, y = np.vstack([x, step.new[ok]]), np.vstack([y, y_new[ok]])
        record = {"round": rounds, "training_points": len(np.unique(x, axis=0)), "forward_runs": spent,
                  "error_nats": _finite(errors[-1]), "quantile_shift": shifts[-1],
                  **_round_record(emulator, step), "seconds_fit_and_sampling": t1 - t0,
                  "seconds_forward": time.perf_counter() - t1}
        logger.info("curve emulator round %d: %d points, error %.2f nats at fresh posterior draws",
                    rounds, record["training_points"], errors[-1])
        if log is not None:
            log(record)
    last = [_finite(e) for e in errors[-VALIDATED_ROUNDS:]]
    worst = None if not last or None in last else max(last)
    return emulator, x, y, {"evaluations": spent, "converged": converged, "rounds": rounds,
                            "error_nats": worst, "quantile_shift": shifts[-1] if shifts else None,
                            "last_errors_nats": last, "last_quantile_shifts": shifts[-VALIDATED_ROUNDS:],
                            "last_spreads": [_finite(v) for v in spreads[-VALIDATED_ROUNDS:]],
                            "variance_factor": _factor_range(emulator)}


def _fit(features: CurveFeatures, x: Array, y: Array, earlier: CurveEmulator | None,
         recent: list[Array]) -> CurveEmulator:
    """The emulator of the rows ``x`` ``(N, d)`` and features ``y`` ``(N, F)``, its
    correlation's fit started from the ``earlier`` one's and its variances calibrated at the
    last :data:`VALIDATED_ROUNDS` batches of ``recent`` rows (where the rounds sample, not
    over the exploration's far points)."""
    emulator = CurveEmulator(features, x, y, start=earlier)
    if recent:
        emulator.calibrate(np.vstack(recent[-VALIDATED_ROUNDS:]))
    return emulator


def _fresh_error(emulator: CurveEmulator, n_eff: float, step: _Round, y_new: Array,
                 ok: NDArray[np.bool_]) -> float:
    """The mean |emulated - simulated| log-likelihood (nats) at the round's successfully
    simulated posterior draws, weighted by ``step.error_weight`` so that it estimates the
    mean at draws of the emulated posterior, from their features ``y_new`` ``(B, F)``;
    infinite when none succeeded."""
    at = ok[:step.posterior]
    if not np.any(at):
        return float("inf")
    a = 0.5 * n_eff
    emulated = -a * np.log(np.maximum(emulator.loss(step.new[:step.posterior][at], variance=EXPECTED_LOSS),
                                      1e-300))
    exact = -a * np.log(np.maximum(emulator.features.loss(y_new[:step.posterior][at]), 1e-300))
    return float(np.average(np.abs(emulated - exact), weights=step.error_weight[at]))


def _factor_range(emulator: CurveEmulator) -> dict[str, float] | None:
    """The rows that calibrated the emulator's output variances and the least, median and
    largest factor of the outputs with a variance; ``None`` when none calibrated them."""
    if not emulator.calibration_rows:
        return None
    factor = emulator.variance_factor[emulator.scale2 > 0.0]
    return {"rows": emulator.calibration_rows, "min": float(np.min(factor)),
            "median": float(np.median(factor)), "max": float(np.max(factor))}


def _round_record(emulator: CurveEmulator, step: _Round) -> dict[str, Any]:
    """What ``refine.jsonl`` keeps of a round's sample, spread and emulator."""
    return {"spread": _finite(step.spread), "importance_ess": step.sample.ess, "k_hat": step.sample.k_hat,
            **step.aim,
            "components": emulator.components, "lengthscales": emulator.corr.lengthscales.tolist(),
            "variance_factor": emulator.variance_factor.tolist()}


def _finite(value: float) -> float | None:
    """``value`` as a float, ``None`` where it is not finite (JSON has no infinity)."""
    return float(value) if np.isfinite(value) else None


def _validated(errors: list[float], shifts: list[float | None], tolerance_nats: float,
               spreads: list[float]) -> bool:
    """The last :data:`VALIDATED_ROUNDS` rounds validate the emulator and their mean
    spread is small (see :func:`learn`)."""
    recent = shifts[-VALIDATED_ROUNDS:]
    return (len(recent) == VALIDATED_ROUNDS and all(s is not None and s <= QUANTILE_SHIFT for s in recent)
            and all(e <= tolerance_nats for e in errors[-VALIDATED_ROUNDS:])
            and bool(np.mean(spreads[-VALIDATED_ROUNDS:]) <= SPREAD_MAX))


def curve_posterior(ctx: RunContext, start: Array, n_eff: float, settings: PosteriorSpec,
                    rng: np.random.Generator, out_dir: Path
                    ) -> tuple[CurveEmulation, dict[str, Any], tuple[Array, Array]]:
    """The curve emulator's active learning from the calibration GP's points ``start``
    ``(N, d)`` (unit cube).

    Returns:
        The emulator, the active learning's record (``enabled``, ``kind``, ``evaluations``
        (the starting points' runs included), ``start_runs``, ``converged``,
        ``error_nats``, ``rounds``) and the emulator's data ``(x_unit (N, d), log_loss (N,))``.

    Raises:
        SurrogateError: fewer starting points simulated successfully than the emulator's
            linear trend needs.
    """
    features = CurveFeatures(ctx.problem)
    space = ctx.space

    def simulate(u: Array) -> tuple[Array, NDArray[np.bool_]]:
        return features.of(ctx.runner.simulate(space.from_unit(u), features.ids))

    start = np.asarray(start, dtype=float)
    y0, ok = simulate(start)
    if np.count_nonzero(ok) < space.dim + 2:
        raise SurrogateError(f"only {np.count_nonzero(ok)} of the calibration's {len(start)} points "
                             "simulated successfully again; the curve emulator needs at least "
                             f"{space.dim + 2} (the forward runs' failures are in the calibration's "
                             "evaluations.jsonl)")
    log_path = out_dir / "refine.jsonl"
    log_path.unlink(missing_ok=True)

    def log(record: dict[str, Any]) -> None:
        with log_path.open("a", encoding="utf-8") as fh:
            fh.write(json.dumps(record) + "\n")

    emulator, x, y, record = learn(simulate, features, start[ok], y0[ok], n_eff, int(settings.refine),
                                   settings.refine_tolerance_nats, rng, log, settings.walkers,
                                   settings.correction)
    active = {"enabled": True, "kind": "curves", **record, "start_runs": int(start.shape[0]),
              "tolerance_nats": float(settings.refine_tolerance_nats),
              "evaluations": record["evaluations"] + int(start.shape[0]), "components": emulator.components}
    return CurveEmulation(emulator, n_eff), active, (x, np.log(features.loss(y)))


def curve_chains(emulation: CurveEmulation, settings: PosteriorSpec,
                 rng: np.random.Generator) -> list[Chains]:
    """The emcee chains (one ensemble, at most :data:`CHAIN_STEPS` steps) of the emulated
    posterior, from the best training point."""
    emulator = emulation.emulator
    centre = emulator.x[np.argmin(emulator.features.loss(emulator.y))]
    if settings.steps > CHAIN_STEPS:
        logger.info("curve emulator: %d emcee steps, not %d: the chains only start the importance sampling",
                    CHAIN_STEPS, settings.steps)
    return [sample_chains(emulator, emulation.n_eff, rng, centre, 1.0, min(settings.steps, CHAIN_STEPS),
                          settings.walkers, variance=EXPECTED_LOSS, label=" (curve emulator)")]


def _emulator_sample(emulator: CurveEmulator, n_eff: float, start: Array, spec: CorrectionSettings,
                     draws: int, rng: np.random.Generator, aim: float = 0.0,
                     per_iteration: int = EMULATOR_ITERATION) -> ImportanceSample:
    """The emulated posterior (of the expected loss) by adaptive importance sampling from the
    draws ``start`` ``(S, d)``: the correction's algorithm with the emulator as its target,
    at most ``draws`` emulator evaluations in iterations of ``per_iteration`` and no forward
    run.  It is settled at the correction's k-hat target and an ESS of at least the
    correction's target and ``2 * ROUND_ESS``, and once settled draws on to an ESS of ``aim``."""
    run = spec.model_copy(update={"draws": draws, "batch": EMULATOR_BATCH, "per_iteration": per_iteration,
                                  "ess_target": max(spec.ess_target, 2 * ROUND_ESS)})
    if len(start) > START_ROWS:  # the first proposal's mixture fit needs no more
        start = start[rng.choice(len(start), START_ROWS, replace=False)]
    with warnings.catch_warnings():
        # the correction's own warnings name its forward-model options; the stage's
        # reliability reasons say what an unsettled sample of the emulator means
        warnings.simplefilter("ignore", SmcBayesWarning)
        sample = correct(log_posterior(emulator, n_eff, variance=EXPECTED_LOSS), start, run, rng,
                         label="importance sampling of the emulator", runs="emulator evaluations", aim=aim)
    return dataclasses.replace(sample, target="emulator", warnings=[])


def sample_emulator(emulator: CurveEmulator, n_eff: float, start: Array, spec: CorrectionSettings,
                    rng: np.random.Generator) -> ImportanceSample:
    """The emulated posterior (of the expected loss) by adaptive importance sampling from
    the draws ``start`` ``(S, d)``, aiming at an ESS of :data:`FINAL_ESS`: at most
    :data:`EMULATOR_DRAWS` emulator evaluations, as many once more when the weights have not
    settled at the correction's targets; no forward run."""
    def draw(rows: Array) -> ImportanceSample:
        return _emulator_sample(emulator, n_eff, rows, spec, EMULATOR_DRAWS, rng, FINAL_ESS, FINAL_ITERATION)

    sample = draw(start)
    if not sample.settled:
        logger.info("the emulator's importance sample has not settled (ESS %.0f, k-hat %.2f): "
                    "drawing %d more", sample.ess, sample.k_hat, EMULATOR_DRAWS)
        sample = draw(np.vstack([start, sample.resample(len(start), rng)]))
    return sample


def importance_sample(emulation: CurveEmulation, chains: list[Chains], settings: PosteriorSpec,
                      rng: np.random.Generator) -> ImportanceSample:
    """The reported emulated posterior: :func:`sample_emulator` from the emcee draws.

    The emcee chains, started at the best point, under-sample a flat arm of the posterior:
    on the accuracy benchmark's first case they put 1.2 % of the mass where the emulated
    posterior, sampled by importance, puts 9-10 % and the exact one 6.5 %; the importance
    sampler's proposals, fitted to the tempered posterior, spread into it.
    """
    d = emulation.emulator.x.shape[1]
    start = np.concatenate([c.samples.reshape(-1, d) for c in chains])
    return sample_emulator(emulation.emulator, emulation.n_eff, start, settings.correction, rng)
