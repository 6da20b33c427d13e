"""The posterior stage's curve emulator path (``--emulator curves``): active learning of
the force-curve emulator of :mod:`smcbayes.posterior.curves`, confirmed by its reported
posterior.

Starts from the calibration GP's points (their curves the calibration's, or simulated where
it did not keep them), then runs rounds of ``round_runs`` forward runs, each chosen by
:func:`~smcbayes.posterior.curve_round.next_round`: mostly draws of the emulated posterior
where the emulator's GP sample functions disagree, the rest exploring.  Two measures decide
when to stop, in each of the last ``VALIDATED_ROUNDS`` rounds: the emulator's error at
the round's posterior draws, measured before they join its data (mean absolute, nats of
log-likelihood, each draw weighted back to the posterior's share; at most
``refine_tolerance_nats``), and how far the emulated posterior's quantiles moved
(:func:`~smcbayes.posterior.curve_sample.quantile_shift`, on common draws, so that the
sampling noise cancels; at most ``QUANTILE_SHIFT``, each round and over those rounds);
the same rounds' sample functions must also move it by at most
:data:`~smcbayes.posterior.spread.SPREAD_MAX` on average.  A
validated emulator's reported posterior (that of the expected loss,
:data:`~smcbayes.posterior.curve_sample.EXPECTED_LOSS`, sampled by importance on the
emulator and pooled with its sample functions' posteriors,
:mod:`smcbayes.posterior.curve_sample`) is then drawn, and the learning stops only if its
own spread is within the bound too; after ``CONFIRMATIONS`` failed confirmations it asks
for no more before its budget's end.  At the budget's end the last rounds count towards a
validation whether they ran before or after a failed confirmation.  A stage whose budget
runs out first is reported unreliable.  ``refine.jsonl`` logs each round.  The learning's
progress, its measures and the constants named here are in
:mod:`smcbayes.posterior.curve_progress`."""

from __future__ import annotations

import dataclasses
import json
import logging
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from smcbayes.config import PosteriorSpec
from smcbayes.config.settings import ROUND_RUNS_CURVES
from smcbayes.errors import SurrogateError
from smcbayes.posterior.context import RunContext, start_curves
from smcbayes.posterior.correct import CorrectionSettings
from smcbayes.posterior.curve_progress import (
    VALIDATED_ROUNDS,
    LearningProgress,
    confirmed,
    finite,
    log_drift,
    round_status,
)
from smcbayes.posterior.curve_round import Round, next_round
from smcbayes.posterior.curve_sample import (
    EXPECTED_LOSS,
    ROUND_ESS,
    START_ROWS,
    CurveEmulation,
    FinalPosterior,
    final_posterior,
    quantile_shift,
)
from smcbayes.posterior.curve_spread import curve_spread
from smcbayes.posterior.curves import CurveEmulator, CurveFeatures, log_posterior

logger = logging.getLogger(__name__)

Array = NDArray[np.float64]

@dataclass
class Learned:
    """What the active learning leaves.

    Attributes:
        emulator: the last emulator.
        x, y: its data: unit-cube rows ``(N, d)`` and features ``(N, F)``.
        record: the record of the active learning (see :func:`learn`).
        final: the last emulator's reported posterior, when a confirmation drew it
            (``None`` otherwise).
        draws: draws ``(S, d)`` of the last round's emulated posterior (``None`` when no
            round ran), from which the reported posterior's sampling can start.
    """

    emulator: CurveEmulator
    x: Array
    y: Array
    record: dict[str, Any]
    final: FinalPosterior | None
    draws: Array | None = None


def learn(simulate: Callable[[Array], tuple[Array, NDArray[np.bool_]]], features: CurveFeatures,
          x: Array, y: Array, n_eff: float, budget: int, tolerance_nats: float, rng: np.random.Generator,
          log: Callable[[dict[str, Any]], None] | None = None, walkers: int = 32,
          spec: CorrectionSettings | None = None,
          confirm: Callable[[CurveEmulator, Array | None], FinalPosterior] | None = None,
          round_runs: int = ROUND_RUNS_CURVES) -> Learned:
    """Active learning until validated (and confirmed) or ``budget`` further runs are spent.

    The emulator is validated when, in each of the last ``VALIDATED_ROUNDS`` rounds,
    its mean absolute error at the round's fresh posterior draws (weighted back to the
    posterior's shares, :func:`~smcbayes.posterior.curve_aim.targeted`; measured before they
    join its data) is at most ``tolerance_nats`` and the quantiles of the emulated
    posterior moved by at most ``QUANTILE_SHIFT``, each round and over those rounds
    (``LearningProgress.drift``), and the same rounds' sample functions
    moved them by at most :data:`~smcbayes.posterior.spread.SPREAD_MAX` on average (one
    round's, on one support of a thin sample, is too noisy to stop at).  With ``confirm``,
    a validated emulator's reported posterior is drawn and the learning stops only if its own
    spread (several supports of a larger sample) is at most ``SPREAD_MAX`` too: the rounds'
    spread and the reported one differ by 0.01-0.07 either way on the measured thesis trials,
    and a stop on the rounds' alone ended learnings whose reported posterior was then called
    unreliable.  After a failed confirmation the next rounds start from its sample, and
    ``VALIDATED_ROUNDS`` new rounds must validate before the next; after
    ``CONFIRMATIONS`` failed ones the learning runs to its budget.  At the budget's end
    no new round can follow: the last ``VALIDATED_ROUNDS`` rounds count towards the
    validation whether they ran before or after the last failed confirmation, and a
    validation is confirmed once more; a confirmation that passes after another is measured
    again on fresh supports by the stage (:func:`curve_posterior`).

    Args:
        simulate: unit-cube rows ``(P, d)`` -> features ``(P, F)`` and success ``(P,)``.
        features: the feature map.
        x, y: starting rows ``(N, d)`` and their features ``(N, F)`` (successful rows only).
        n_eff: effective points of the likelihood.
        budget: most forward runs of the active learning.
        tolerance_nats: the out-of-sample error that validates a round.
        log: receives one record per round.
        spec: settings of the rounds' importance sampling (the correction's by default).
        confirm: draws an emulator's reported posterior (no forward run), given draws
            ``(S, d)`` of the last round's emulated posterior to start from (``None``
            before the first round).
        round_runs: forward runs per round (one batch through the executor; the last
            round takes what is left of ``budget``).

    Returns:
        The last emulator, its data, its reported posterior if a confirmation drew it, draws of
        the last round's posterior (``None`` when no round ran), and the record of the active
        learning (``evaluations``, ``converged``, ``rounds``, ``error_nats`` (the worst of the
        last rounds' errors), ``quantile_shift`` (the last round's), ``last_errors_nats`` and
        ``last_quantile_shifts`` (those of the last ``VALIDATED_ROUNDS`` rounds; ``None``
        for a round with nothing to compare, or a sample too thin to tell), ``last_spreads``
        (those of the last ``VALIDATED_ROUNDS`` rounds), ``drift`` (the posterior's move over
        them, ``LearningProgress.drift``; ``None`` unless their other measures passed),
        ``drifts`` (every drift measured, after how many ``rounds``), ``validated_rounds`` and
        ``bounds`` (those the stop asks of the move, the drift and the mean spread),
        ``confirmations`` (after how many
        ``rounds`` and ``forward_runs`` each was drawn, its ``spread`` and ``spread_se``,
        whether it ``passed`` and its ``seconds``), ``validated_at_budget_end`` (the last
        validation counted rounds from before a failed confirmation, which only the budget's end
        allows) and ``variance_factor`` (the last emulator's calibration of its output
        variances, :meth:`~smcbayes.posterior.curves.CurveEmulator.calibrate`: rows used and
        range; ``None`` when nothing calibrated them)).  The first round has no earlier emulator
        to compare with, so the emulator can be validated after ``VALIDATED_ROUNDS + 1`` rounds
        at the earliest.
    """
    spec = spec or CorrectionSettings()
    progress = LearningProgress(x, y, x[np.argsort(features.loss(y))[:walkers]])
    emulator = None
    while True:
        t0 = time.perf_counter()
        emulator = _fit(features, progress.x, progress.y, emulator, progress.recent)
        final = None
        # a reported posterior that keeps failing would cost a draw every few rounds; at the
        # budget's end the stage draws it anyway, so there it still confirms
        ended = progress.spent >= budget
        asks = confirm is None or progress.may_confirm() or ended
        # after a failed confirmation new rounds must validate before the next one, but at
        # the budget's end none can follow: the last rounds count whenever they ran, and the
        # reported posterior, drawn there anyway, decides by its own spread
        validated = progress.validated(tolerance_nats)
        progress.late = not validated and ended and progress.validated(tolerance_nats, True)
        log_drift(progress)
        converged = (validated or progress.late) and asks
        if converged and confirm is not None:
            t_confirm = time.perf_counter()
            final = confirm(emulator, progress.draws)
            converged = confirmed(progress, final, rng, progress.spent < budget)
            # the confirmation's own time is in its record, not in the next round's
            t0 += time.perf_counter() - t_confirm
        if converged or progress.spent >= budget:
            break
        size = min(round_runs, budget - progress.spent)
        step = next_round(emulator, n_eff, size, progress.start, spec, rng, walkers,
                          explorers=progress.explorers)
        record = _take(progress, step, emulator, n_eff, simulate, rng, t0)
        logger.info("curve emulator round %d: %d points, %s", progress.rounds, record["training_points"],
                    round_status(progress, tolerance_nats, budget))
        if log is not None:
            log(record)
    return Learned(emulator, progress.x, progress.y,
                   {**progress.record(converged), "variance_factor": _factor_range(emulator)}, final,
                   progress.draws)


def _take(progress: LearningProgress, step: Round, emulator: CurveEmulator, n_eff: float,
          simulate: Callable[[Array], tuple[Array, NDArray[np.bool_]]], rng: np.random.Generator,
          t0: float) -> dict[str, Any]:
    """Record the round ``step`` drawn from ``emulator``, simulate its rows, add them to the
    data and return its record for ``refine.jsonl`` (the round's fit began at ``t0``)."""
    unclear = progress.before is None or step.sample.ess < ROUND_ESS
    progress.shifts.append(None if unclear else quantile_shift(step.sample, progress.before))
    progress.spreads.append(step.spread)
    # the drift compares with the emulator VALIDATED_ROUNDS rounds back: keep no more (each
    # holds its factorisation, tens of MB at a thousand points)
    progress.earlier = [*progress.earlier[-VALIDATED_ROUNDS:],
                        log_posterior(emulator, n_eff, variance=EXPECTED_LOSS)]
    progress.sample = step.sample
    progress.start = step.sample.resample(3 * START_ROWS // 4, rng)
    progress.explorers = step.explorers
    t1 = time.perf_counter()
    y_new, ok = simulate(step.new)
    progress.spent, progress.rounds = progress.spent + len(step.new), progress.rounds + 1
    progress.errors.append(_fresh_error(emulator, n_eff, step, y_new, ok))
    progress.recent.append(step.new[ok])
    progress.x, progress.y = np.vstack([progress.x, step.new[ok]]), np.vstack([progress.y, y_new[ok]])
    return {"round": progress.rounds, "training_points": len(np.unique(progress.x, axis=0)),
            "forward_runs": progress.spent, "error_nats": finite(progress.errors[-1]),
            "quantile_shift": progress.shifts[-1], **_round_record(emulator, step),
            "seconds_fit_and_sampling": t1 - t0, "seconds_forward": time.perf_counter() - t1}


def _fit(features: CurveFeatures, x: Array, y: Array, earlier: CurveEmulator | None,
         recent: list[Array]) -> CurveEmulator:
    """The emulator of the rows ``x`` ``(N, d)`` and features ``y`` ``(N, F)``, its
    correlation's fit started from the ``earlier`` one's and its variances calibrated at the
    last ``VALIDATED_ROUNDS`` batches of ``recent`` rows (where the rounds sample, not
    over the calibration's far points)."""
    emulator = CurveEmulator(features, x, y, start=earlier)
    if recent:
        emulator.calibrate(np.vstack(recent[-VALIDATED_ROUNDS:]))
    return emulator


def _fresh_error(emulator: CurveEmulator, n_eff: float, step: Round, y_new: Array,
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


def _round_record(emulator: CurveEmulator, step: Round) -> dict[str, Any]:
    """What ``refine.jsonl`` keeps of a round's sample, spread and emulator."""
    return {"spread": finite(step.spread), "importance_ess": step.sample.ess, "k_hat": step.sample.k_hat,
            **step.aim,
            "components": emulator.components, "lengthscales": emulator.corr.lengthscales.tolist(),
            "variance_factor": emulator.variance_factor.tolist()}


def curve_posterior(ctx: RunContext, start: Array, n_eff: float, settings: PosteriorSpec,
                    rng: np.random.Generator, out_dir: Path
                    ) -> tuple[CurveEmulation, dict[str, Any], tuple[Array, Array], FinalPosterior | None]:
    """The curve emulator's active learning from the calibration GP's points ``start``
    ``(N, d)`` (unit cube; their curves taken from the calibration's cache where it kept
    them, :meth:`~smcbayes.run.directory.RunDir.calibration_cache`, else simulated) and,
    when the stage reports the emulated posterior (no
    correction), that posterior (:func:`~smcbayes.posterior.curve_sample.final_posterior`),
    which confirms a validated active learning before it stops (:func:`learn`).  A
    confirmation that passes after a failed one is measured again on fresh supports
    (``emulator_spread`` keeps the confirming reading as ``confirmed_shift``); one that
    fails needs no second reading, as none chose it for being low.

    Returns:
        The emulator, the active learning's record (``enabled``, ``kind``, ``evaluations``
        (the starting points' runs included), ``start_runs`` (the starting points the stage
        ran, :func:`~smcbayes.posterior.context.start_curves`), ``start_runs_from_calibration``
        (those whose curves the calibration kept), ``converged``,
        ``error_nats``, ``rounds``, ``confirmations`` (their ``forward_runs`` counted as
        ``evaluations``)), the emulator's data
        ``(x_unit (N, d), log_loss (N,))`` and the reported posterior (``None`` with the
        correction).

    Raises:
        SurrogateError: fewer starting points simulated successfully than the emulator's
            linear trend needs.
    """
    features = CurveFeatures(ctx.problem)
    space = ctx.space

    def simulate(u: Array) -> tuple[Array, NDArray[np.bool_]]:
        return features.of(ctx.runner.simulate(space.from_unit(u), features.ids))

    start = np.asarray(start, dtype=float)
    curves, reused, runs = start_curves(ctx, start, features.ids)
    y0, ok = features.of(curves)
    if np.count_nonzero(ok) < space.dim + 2:
        raise SurrogateError(f"only {np.count_nonzero(ok)} of the calibration's {len(start)} points "
                             "have curves (kept or simulated); the curve emulator needs at least "
                             f"{space.dim + 2} (the forward runs' failures are in the calibration's "
                             "evaluations.jsonl)")
    log_path = out_dir / "refine.jsonl"
    log_path.unlink(missing_ok=True)

    def log(record: dict[str, Any]) -> None:
        with log_path.open("a", encoding="utf-8") as fh:
            fh.write(json.dumps(record) + "\n")

    reported = settings.correct_draws == 0

    def final(emulator: CurveEmulator, draws: Array | None = None) -> FinalPosterior:
        return final_posterior(CurveEmulation(emulator, n_eff), settings, space.free_names, rng,
                               spread=not ctx.noise_free, start=draws)

    # a noise-free likelihood is degenerate: no spread to confirm (it does not learn either)
    learned = learn(simulate, features, start[ok], y0[ok], n_eff, int(settings.refine),
                    settings.refine_tolerance_nats, rng, log, settings.walkers, settings.correction,
                    final if reported and not ctx.noise_free else None, int(settings.round_runs))
    active = {"enabled": True, "kind": "curves", **learned.record, "start_runs": runs,
              "start_runs_from_calibration": reused,
              "tolerance_nats": float(settings.refine_tolerance_nats),
              "evaluations": learned.record["evaluations"] + runs, "components": learned.emulator.components,
              # counted as the stage's active learning counts them, its starting points included
              "confirmations": [{**c, "forward_runs": c["forward_runs"] + runs}
                                for c in learned.record["confirmations"]]}
    posterior = learned.final
    if posterior is None:
        posterior = final(learned.emulator, learned.draws) if reported else None
    elif len(active["confirmations"]) > 1 and active["confirmations"][-1]["passed"]:
        posterior = _measured_again(posterior, CurveEmulation(learned.emulator, n_eff), space.free_names, rng)
    data = (learned.x, np.log(features.loss(learned.y)))
    return CurveEmulation(learned.emulator, n_eff), active, data, posterior


def _measured_again(final: FinalPosterior, emulation: CurveEmulation, names: Sequence[str],
                    rng: np.random.Generator) -> FinalPosterior:
    """``final`` with its spread and pool drawn again on fresh supports: after a failed
    confirmation the learning stops at the first reading within the bound, and that
    reading, chosen for being low, would also be the verdict's."""
    t0 = time.perf_counter()
    spread, pooled = curve_spread(emulation.emulator, emulation.n_eff, final.sample, names, rng)
    spread["confirmed_shift"] = final.max_shift
    return dataclasses.replace(final, spread=spread, pooled=pooled,
                               seconds={**final.seconds, "spread": time.perf_counter() - t0})
