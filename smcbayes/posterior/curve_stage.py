"""The posterior stage's curve emulator path (``--emulator curves``): active learning of
the force-curve emulator of :mod:`smcbayes.posterior.curves` and the emcee sampling of its
posterior.

Starts from the calibration GP's points (simulated again for their curves, through the
stage's forward cache), then runs rounds of ``batch`` forward runs: half random draws of
the emulated posterior, half of the tempered one (likelihood^``temper``) of the optimistic
loss (curves one emulator sd closer to the data), which reaches regions the emulator's
mean rates too low because it has no points there.  The emulator's error at the round's
posterior draws, measured before they join its data, decides when to stop: at most
``refine_tolerance_nats`` (mean absolute, nats of log-likelihood), with the posterior's
quantiles stable, in :data:`VALIDATED_ROUNDS` rounds in a row; a stage whose budget runs
out first is reported unreliable.  ``refine.jsonl`` logs each round.  The reported
posterior is that of the GP mean's curves, sampled by importance on the emulator
(:func:`importance_sample`): the variance term of
:meth:`~smcbayes.posterior.curves.CurveEmulator.loss` lowers the likelihood wherever the
emulator has few points, and on the accuracy benchmark's first case, after 140-380 runs,
its posterior was further from the exact one.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from smcbayes.config import PosteriorSpec
from smcbayes.errors import SmcBayesWarning
from smcbayes.posterior.context import RunContext
from smcbayes.posterior.correct import ImportanceSample, correct
from smcbayes.posterior.curves import CurveEmulator, CurveFeatures, log_posterior
from smcbayes.posterior.sampler import Chains, SamplerSettings, run_ensemble

logger = logging.getLogger(__name__)

Array = NDArray[np.float64]

BATCH = 40
"""Forward runs per round (one batch through the executor)."""

TEMPER = 0.25
"""Exponent of the exploration's likelihood."""

VALIDATED_ROUNDS = 3
"""Rounds in a row whose out-of-sample error is within the tolerance and whose posterior
quantiles moved by at most :data:`QUANTILE_SHIFT`, to stop."""

QUANTILE_SHIFT = 0.05
"""Largest move of a 5/50/95 % quantile of the emulated posterior between rounds (share of
the unit cube) that a validated round allows."""

ROUND_STEPS = 3000
"""Most emcee steps of a round's sampling (the tempered one: half)."""

EMULATOR_DRAWS = 40000
"""Proposal draws of the importance sampling of the emulated posterior (emulator
evaluations, no forward run)."""


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
        """Emulated log loss ``(P,)`` at unit-cube points ``(P, d)`` (of the mean curves, as sampled)."""
        return np.log(np.maximum(self.emulator.loss(np.atleast_2d(u)), 1e-300))


def sample_chains(emulator: CurveEmulator, n_eff: float, rng: np.random.Generator, centre: Array,
                  temper: float = 1.0, steps: int = ROUND_STEPS, walkers: int = 32,
                  variance: bool = False, label: str = "", optimistic: bool = False) -> Chains:
    """emcee chains (differential evolution, from ``centre`` ``(d,)``) of the emulated
    posterior, tempered by ``temper``, of the loss ``variance`` and ``optimistic`` ask for
    (:meth:`~smcbayes.posterior.curves.CurveEmulator.loss`)."""
    settings = SamplerSettings(walkers=walkers, max_steps=steps, min_steps=min(500, steps), moves="de")
    return run_ensemble(log_posterior(emulator, n_eff, temper, variance, optimistic), emulator.x.shape[1],
                        settings, rng, centre, label)


def learn(simulate: Callable[[Array], tuple[Array, NDArray[np.bool_]]], features: CurveFeatures,
          x: Array, y: Array, n_eff: float, budget: int, tolerance_nats: float, rng: np.random.Generator,
          log: Callable[[dict[str, Any]], None] | None = None,
          walkers: int = 32) -> tuple[CurveEmulator, Array, Array, dict[str, Any]]:
    """Active learning until validated or ``budget`` further runs are spent.

    Args:
        simulate: unit-cube rows ``(P, d)`` -> features ``(P, F)`` and success ``(P,)``.
        features: the feature map.
        x, y: starting rows ``(N, d)`` and their features ``(N, F)`` (successful rows only).
        n_eff: effective points of the likelihood.
        budget: most forward runs of the active learning.
        tolerance_nats: the out-of-sample error that validates a round.
        log: receives one record per round.

    Returns:
        The last emulator, its data and the record of the active learning (``evaluations``,
        ``converged``, ``error_nats``, ``rounds``).
    """
    spent, validated, error, rounds, shift, last = 0, 0, None, 0, None, None
    a = 0.5 * n_eff
    while True:
        t0 = time.perf_counter()
        emulator = CurveEmulator(features, x, y)
        if validated >= VALIDATED_ROUNDS or spent >= budget:
            break
        centre = x[np.argmin(features.loss(y))]
        d = x.shape[1]
        draws = sample_chains(emulator, n_eff, rng, centre, 1.0, ROUND_STEPS, walkers).samples.reshape(-1, d)
        wide = sample_chains(emulator, n_eff, rng, centre, TEMPER, ROUND_STEPS // 2, walkers,
                             optimistic=True).samples
        wide = wide.reshape(-1, d)
        size = min(BATCH, budget - spent)
        half = max(1, size // 2)
        # short chains (few walkers, long autocorrelation) may hold fewer rows than asked for
        new = np.vstack([draws[rng.choice(len(draws), half, replace=half > len(draws))],
                         wide[rng.choice(len(wide), size - half, replace=size - half > len(wide))]])
        quantiles = np.quantile(draws, [0.05, 0.5, 0.95], axis=0)
        shift = None if last is None else float(np.max(np.abs(quantiles - last)))
        last = quantiles
        t1 = time.perf_counter()
        y_new, ok = simulate(new)
        spent += size
        rounds += 1
        # the error at the posterior draws, before they join the data
        at = ok[:half]
        emulated = -a * np.log(np.maximum(emulator.loss(new[:half][at]), 1e-300))
        exact = -a * np.log(np.maximum(features.loss(y_new[:half][at]), 1e-300))
        error = float(np.mean(np.abs(emulated - exact))) if np.any(at) else float("inf")
        stable = shift is not None and shift <= QUANTILE_SHIFT
        validated = validated + 1 if error <= tolerance_nats and stable else 0
        x, y = np.vstack([x, new[ok]]), np.vstack([y, y_new[ok]])
        record = {"round": rounds, "training_points": len(x), "forward_runs": spent, "error_nats": error,
                  "quantile_shift": shift,
                  "components": emulator.components, "lengthscales": emulator.corr.lengthscales.tolist(),
                  "seconds_fit_and_sampling": t1 - t0, "seconds_forward": time.perf_counter() - t1}
        logger.info("curve emulator round %d: %d points, error %.2f nats at fresh posterior draws",
                    rounds, len(x), error)
        if log is not None:
            log(record)
    return emulator, x, y, {"evaluations": spent, "converged": validated >= VALIDATED_ROUNDS,
                            "error_nats": error, "quantile_shift": shift, "rounds": rounds}


def curve_posterior(ctx: RunContext, start: Array, n_eff: float, settings: PosteriorSpec,
                    rng: np.random.Generator, out_dir: Path
                    ) -> tuple[CurveEmulation, list[Chains], dict[str, Any], tuple[Array, Array]]:
    """The curve emulator's posterior: active learning from the calibration GP's points
    ``start`` ``(N, d)`` (unit cube), then the emcee chains of the emulated posterior (of
    the GP mean's curves).

    Returns:
        The sampled emulator, its chains (one ensemble), the active learning's record
        (``enabled``, ``kind``, ``evaluations`` (the starting points' runs included),
        ``start_runs``, ``converged``, ``error_nats``, ``rounds``) and the emulator's data
        ``(x_unit (N, d), log_loss (N,))``.
    """
    features = CurveFeatures(ctx.problem)
    space = ctx.space

    def simulate(u: Array) -> tuple[Array, NDArray[np.bool_]]:
        return features.of(ctx.runner.simulate(space.from_unit(u), features.ids))

    start = np.asarray(start, dtype=float)
    y0, ok = simulate(start)
    log_path = out_dir / "refine.jsonl"
    log_path.unlink(missing_ok=True)

    def log(record: dict[str, Any]) -> None:
        with log_path.open("a", encoding="utf-8") as fh:
            fh.write(json.dumps(record) + "\n")

    emulator, x, y, record = learn(simulate, features, start[ok], y0[ok], n_eff, int(settings.refine),
                                   settings.refine_tolerance_nats, rng, log, settings.walkers)
    centre = x[np.argmin(features.loss(y))]
    chains = [sample_chains(emulator, n_eff, rng, centre, 1.0, settings.steps, settings.walkers,
                            label=" (curve emulator)")]
    active = {"enabled": True, "kind": "curves", **record, "start_runs": int(start.shape[0]),
              "evaluations": record["evaluations"] + int(start.shape[0]), "components": emulator.components}
    return CurveEmulation(emulator, n_eff), chains, active, (x, np.log(features.loss(y)))


def importance_sample(emulation: CurveEmulation, chains: list[Chains], settings: PosteriorSpec,
                      rng: np.random.Generator) -> ImportanceSample:
    """The emulated posterior by adaptive importance sampling from the emcee draws (the
    correction's algorithm with the emulator as its target: :data:`EMULATOR_DRAWS`
    emulator evaluations, no forward run).

    The emcee chains, started at the best point, under-sample a flat arm of the posterior:
    on the accuracy benchmark's first case they put 1.2 % of the mass where the emulated
    posterior, sampled by importance, puts 9-10 % and the exact one 6.5 %; the importance
    sampler's proposals, fitted to the tempered posterior, spread into it.
    """
    d = emulation.emulator.x.shape[1]
    start = np.concatenate([c.samples.reshape(-1, d) for c in chains])
    spec = settings.correction.model_copy(update={"draws": EMULATOR_DRAWS})
    with warnings.catch_warnings():
        # the correction's own warnings name its forward-model options; the stage's
        # reliability reasons say what an unsettled sample of the emulator means
        warnings.simplefilter("ignore", SmcBayesWarning)
        sample = correct(log_posterior(emulation.emulator, emulation.n_eff, variance=False), start, spec, rng)
    return dataclasses.replace(sample, target="emulator", warnings=[])
