"""The posterior stage of a calibration run directory (``smcbayes posterior``).

Reads the run (its resolved config, GP state and best point), estimates the effective
number of independent points from the residuals at the best point, refines the emulator
(rounds of forward evaluations at random, most uncertain and space-filling points of the
emulated posterior's region, stopped early once the out-of-sample error at fresh posterior
draws is below ``refine_tolerance_nats`` and GP sample functions no longer move it; see
:func:`~smcbayes.posterior.active.refine` and :mod:`smcbayes.posterior.refine`), samples
the emulated posterior (of the GP mean, or a mixture over GP sample functions), measures
how far the emulator's uncertainty moves it (:mod:`smcbayes.posterior.spread`; for the
curve emulator :mod:`smcbayes.posterior.curve_spread`) and pools the sample functions'
posteriors of that check with the GP mean's (``pool_functions``),
checks the emulator against the forward model at posterior draws and writes
``RUN_DIR/posterior/``: ``posterior.nc`` (arviz InferenceData), ``summary.json``,
``summary.csv``, figures (corner, correlations, predictive bands, the curve emulator's
active learning round by round; PNG and SVG) and, after
refinement, ``gp_refined.pt`` and ``refine.jsonl``.
"""

from __future__ import annotations

import logging
import time
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from smcbayes.config import PosteriorSpec
from smcbayes.data.loss import best_offsets_mm, force_pair
from smcbayes.errors import StaleRunsWarning, UnreliablePosteriorWarning
from smcbayes.forward.nodes import interp_rows
from smcbayes.posterior.active import SPREAD_STEPS, fit_local, refine_stage, sample, spread_chains
from smcbayes.posterior.context import (
    RunContext,
    emulator_start,
    exact_log_posterior,
    load_run,
    true_log_loss,
)
from smcbayes.posterior.correct import ImportanceSample, correct
from smcbayes.posterior.crossfit import LocalFit
from smcbayes.posterior.curve_sample import FinalPosterior, curve_chains
from smcbayes.posterior.curve_spread import CURVE_FUNCTIONS, SPREAD_SUPPORTS
from smcbayes.posterior.curve_stage import curve_posterior
from smcbayes.posterior.curves import CurveFeatures, CurveLossUnsupported
from smcbayes.posterior.likelihood import effective_points, sandwich_points
from smcbayes.posterior.reliability import assess
from smcbayes.posterior.report import learning_figures, write_outputs
from smcbayes.posterior.sampler import Chains
from smcbayes.posterior.summary import stack_components
from smcbayes.posterior.threads import emulator_threads
from smcbayes.run import RunDir
from smcbayes.simulation.executors.base import Executor
from smcbayes.surrogate.gp import gp_session, load_surrogate

logger = logging.getLogger(__name__)

Array = NDArray[np.float64]

PosteriorSettings = PosteriorSpec
"""The stage's settings are the ``[posterior]`` table (one model, one set of defaults)."""

__all__ = ["PosteriorSettings", "RunContext", "exact_log_posterior", "load_run", "run_posterior",
           "true_log_loss"]


SENSITIVITY_STEP = 0.02
"""Finite-difference step of the force sensitivities (unit-cube coordinates): well above
the roughness of the discrete solver's loss (about 1e-3)."""


def local_fit(ctx: RunContext) -> LocalFit:
    """Force residuals and sensitivities at the best point on every training configuration.

    Central differences of step :data:`SENSITIVITY_STEP` in the unit cube: 2 d + 1
    parameter rows, each simulated on every training configuration (at the best point's
    contact offset where the loss profiles it, at their own where it is measured from the end
    state); the perturbed forces are read on the best
    point's loss grid.  ``usable`` is false where a perturbed run fails.
    """
    p, space = ctx.problem, ctx.space
    u0 = space.to_unit(ctx.best_theta)[0]
    d = u0.size
    up, down = np.minimum(u0 + SENSITIVITY_STEP, 1.0), np.maximum(u0 - SENSITIVITY_STEP, 0.0)
    rows = np.repeat(u0[None, :], 2 * d + 1, axis=0)
    rows[1 + np.arange(d), np.arange(d)] = up
    rows[1 + d + np.arange(d), np.arange(d)] = down
    theta = space.from_unit(rows)
    # the best point as the calibration ran it (the unit cube's round trip may change its
    # last bit), so that its kept run is found
    theta[0] = ctx.best_theta[0]
    results = ctx.runner.simulate(theta, p.train_ids)
    residuals, sensitivities, usable = [], [], True
    for cid in p.train_ids:
        m, spec = p.dataset.measurements[cid], p.project.loss
        # every row at the best point's own contact offset, where the loss profiles it: the
        # sensitivities in the parameters alone, free of the offset's grid steps (an offset
        # measured from the end state moves with the parameters, as in the loss)
        offset = best_offsets_mm(results[cid], m, spec)[0] if spec.contact_mode == "profile" else None
        pair = force_pair(results[cid], m, spec, offset_mm=offset)
        grid = np.broadcast_to(pair.time_s[:1], pair.time_s.shape)
        sim = interp_rows(grid, pair.time_s, pair.sim_kN)
        residuals.append(pair.meas_kN[0] - sim[0])
        sensitivities.append(((sim[1:1 + d] - sim[1 + d:]) / (up - down)[:, None]).T)
        usable &= bool(np.all(pair.ok))
    return LocalFit(tuple(p.train_ids), u0, tuple(residuals), tuple(sensitivities), usable)


def residual_budget(ctx: RunContext, fit: LocalFit | None = None) -> dict[str, Any]:
    """Effective points from the force residuals and sensitivities at the best point.

    Two estimates: ``n_eff_residual`` = sum_k N_k / tau_k from the residuals' integrated
    autocorrelation times, and the sandwich estimate of
    :func:`~smcbayes.posterior.likelihood.sandwich_points`, which also uses the force
    sensitivities (:func:`local_fit`, computed here when ``fit`` is not given).  The
    likelihood uses the smaller of the two (``n_eff_total``), the residual one alone where
    a perturbed run fails or the data inform no direction.  Each can overstate N_eff: the
    residual estimate when the misfit concentrates where a parameter acts, the sandwich
    when the residuals are correlated over a whole curve (a systematic model error), as
    its lag sums then span the record and the score sums nearly cancel at the optimum.
    """
    fit = fit if fit is not None else local_fit(ctx)
    residuals, sensitivities = list(fit.residuals_kN), list(fit.sensitivities)
    mse = {cid: float(np.mean(r**2)) for cid, r in zip(fit.config_ids, residuals, strict=True)}
    tau, n_eff = effective_points(residuals, centred=False)
    sandwich = sandwich_points(residuals, sensitivities) if fit.usable else float("nan")
    total = (min(sandwich, float(n_eff.sum())) if np.isfinite(sandwich) and sandwich > 0
             else float(n_eff.sum()))
    return {"config_ids": list(fit.config_ids), "tau": tau.tolist(), "n_eff": n_eff.tolist(),
            "n_eff_residual": float(n_eff.sum()), "n_eff_sandwich": sandwich,
            "n_eff_total": total, "mse_kN2": mse}


def correct_posterior(ctx: RunContext, chains: list, n_eff: float, settings: PosteriorSettings,
                      rng: np.random.Generator, data: tuple[Array, Array]) -> Any:
    """Importance-sampling correction of the emulated posterior (see :mod:`smcbayes.posterior.correct`).

    ``data`` are the GP's training points ``(x_unit (K, d), log_loss (K,))``: their exact
    log posterior is known and helps shape the first proposal.
    """
    unit, _ = stack_components(chains)
    cs = settings.correction.model_copy(update={"draws": settings.correct_draws})
    known = (data[0], -0.5 * n_eff * np.asarray(data[1], dtype=float))
    return correct(exact_log_posterior(ctx, n_eff), unit.reshape(-1, ctx.space.dim), cs, rng, known)


def _count_runs(runs: dict[str, int], refine: int, residual_budget: int) -> None:
    """Complete ``forward_evaluations``: the totals of what shaped the posterior
    (``inference``) and of what only checks it or draws its bands (``checks_and_bands``)."""
    runs.update(refine=refine, residual_budget=residual_budget)
    runs["total"] = sum(runs.values())
    runs["inference"] = runs["residual_budget"] + runs["refine"] + runs["correction"]
    runs["checks_and_bands"] = runs["emulator_check"] + runs["bands"]


def _begin(ctx: RunContext, settings: PosteriorSettings) -> tuple[PosteriorSettings, Path]:
    """Start the stage in the run directory; returns the settings it runs with (``auto``
    resolved to an emulator, the defaults of the correction and the active learning that
    depend on it and the simulator filled in, no active learning on noise-free data) and
    its output folder."""
    stale = ctx.stale_calibration_runs
    if stale is not None:
        warnings.warn(stale, StaleRunsWarning, stacklevel=3)
    slow = not ctx.problem.fast
    if ctx.noise_free and settings.correct_draws is None:
        settings = settings.model_copy(update={"correct_draws": 0})  # no weights can resolve a spike
    settings = settings.resolved(slow, curves=_curves_allowed(ctx, settings.emulator))
    if settings.emulator == "curves":
        if settings.functions > 0:
            logger.warning("--functions %d draws sample functions of the log-loss emulator; the curve "
                           "emulator pools its own %d (see --no-pool-functions), so it is ignored",
                           settings.functions, CURVE_FUNCTIONS * SPREAD_SUPPORTS)
    if slow and settings.correct_draws > 0:
        # each correction draw inside the box is one run of the user's solver per configuration
        logger.warning("the importance correction may run the %s up to %d times on each of %d "
                       "configuration(s); --correct-draws 0 reports the emulated posterior without it",
                       "external simulator" if ctx.summary.get("simulator") == "external" else "2-D solver",
                       settings.correct_draws, len(ctx.problem.train_ids))
    out_dir = ctx.run.begin_stage("posterior", settings.model_dump(mode="json"))
    if ctx.noise_free and settings.refine > 0:
        # the likelihood is a spike at the truth: simulator runs cannot make it a posterior
        logger.info("noise-free training curves: no active learning; the posterior will be "
                    "reported unreliable")
        settings = settings.model_copy(update={"refine": 0})
    return settings, out_dir


def _curves_allowed(ctx: RunContext, emulator: str) -> bool:
    """Whether the stage runs the curve emulator: when named (a loss the curves cannot give
    is refused here, before any run), and with ``auto`` where the project's loss is one the
    emulated curves give (:class:`~smcbayes.posterior.curves.CurveFeatures`) and the
    training curves are not noise-free; the log-loss emulator otherwise, and the log says
    why.  On noise-free curves (a truth check) the likelihood is a spike that no posterior
    resolves, and the log-loss emulator reports that from the calibration's GP without
    active learning, where the curve emulator would first simulate the calibration's points
    again."""
    if emulator == "curves":
        CurveFeatures(ctx.problem)
        return True
    if emulator != "auto":
        return False
    if ctx.noise_free:
        logger.info("posterior: the log-loss emulator (emulator 'auto'): the training curves are noise-free")
        return False
    try:
        CurveFeatures(ctx.problem)
    except CurveLossUnsupported as exc:
        logger.info("posterior: the log-loss emulator (emulator 'auto'): %s", exc)
        return False
    return True


def _spread_and_pool(ctx: RunContext, surrogate: Any, n_eff: float, settings: PosteriorSettings,
                     rng: np.random.Generator, chains: list[Chains],
                     ended: int | None) -> tuple[dict[str, Any], list[Chains]]:
    """The emulator's spread around the reported posterior's ``chains`` (the GP mean's, or
    a mixture's requested through ``functions``) and the sample functions' chains to pool
    into the reported posterior (none with ``pool_functions`` off or such a mixture, which
    already carries the GP's uncertainty).  The functions are those of the measurement
    that ended the active learning (drawn with the seed ``ended``), if one did, on chains
    as long as ``chains``, at least :data:`~smcbayes.posterior.active.SPREAD_STEPS` and at
    most ``settings.steps``: a sample function's posterior is rough where the GP is unsure,
    and its stretch-move chains rarely meet the stopping rule at any affordable length."""
    steps = min(settings.steps, max(SPREAD_STEPS, *(c.steps for c in chains)))
    measured = spread_chains(ctx, surrogate, n_eff, settings.model_copy(update={"steps": steps}), rng, ended)
    spread = measured.spread(stack_components(chains)[0].reshape(-1, ctx.space.dim), ctx.space.free_names)
    pooled = measured.functions if settings.pool_functions and settings.functions == 0 else []
    return spread, pooled


@dataclass
class _Emulated:
    """The emulator's active learning and the sampling of its posterior.

    Attributes:
        emulator: the sampled emulator.
        chains: its emcee chains.
        active: the active learning's record.
        data: the emulator's data ``(x_unit (N, d), log_loss (N,))``.
        start_points: what the emulator started from.
        surrogate: the log-loss GP (``None`` for the curve emulator).
        ended: the seed of the measurement that ended the log-loss GP's active learning.
        final: the curve emulator's reported posterior (``None`` for the log-loss GP or
            with the correction).
        seconds: wall time of the active learning and of the sampling.
    """

    emulator: Any
    chains: list[Chains]
    active: dict[str, Any]
    data: tuple[Array, Array]
    start_points: dict[str, int]
    surrogate: Any
    ended: int | None
    final: FinalPosterior | None
    seconds: dict[str, float]


def _emulate(ctx: RunContext, calibration_gp: Any, n_eff: float, settings: PosteriorSettings,
             rng: np.random.Generator, out_dir: Path) -> _Emulated:
    """The emulator's active learning and the sampling of its posterior (for the curve
    emulator without the correction, its reported posterior with the spread)."""
    t0 = time.perf_counter()
    if settings.emulator == "curves":
        emul, active, data, final = curve_posterior(ctx, calibration_gp.x_unit, n_eff, settings, rng, out_dir)
        start_points = {"calibration_gp": int(calibration_gp.x_unit.shape[0]), "local_search": 0}
        if final is not None:
            learning = time.perf_counter() - t0 - final.seconds["sampling"] - final.seconds["spread"]
            return _Emulated(emul, final.chains, active, data, start_points, None, None, final,
                             {"learning": learning, "sampling": final.seconds["sampling"]})
        t_sample = time.perf_counter()
        chains = curve_chains(emul, settings, rng)
        return _Emulated(emul, chains, active, data, start_points, None, None, None,
                         {"learning": t_sample - t0, "sampling": time.perf_counter() - t_sample})
    data = emulator_start(ctx, calibration_gp.x_unit, calibration_gp.log_loss)
    start_points = {"calibration_gp": int(calibration_gp.log_loss.size),
                    "local_search": int(data[1].size - calibration_gp.log_loss.size)}
    surrogate = fit_local(*data, n_eff, calibration_gp.kernel, settings.seed)
    surrogate, data, active, ended = refine_stage(ctx, data, surrogate, n_eff, settings, rng, out_dir)
    t_sample = time.perf_counter()
    emul, chains = sample(ctx, surrogate, n_eff, settings, rng)
    return _Emulated(emul, chains, active, data, start_points, surrogate, ended, None,
                     {"learning": t_sample - t0, "sampling": time.perf_counter() - t_sample})


def _reported(ctx: RunContext, emulated: _Emulated, corrected: ImportanceSample | None, n_eff: float,
              settings: PosteriorSettings, rng: np.random.Generator
              ) -> tuple[ImportanceSample | None, dict[str, Any] | None, list[Chains], bool]:
    """The importance sample to report (the correction's, the curve emulator's, pooled with
    its sample functions' posteriors with ``pool_functions``, or none), the emulator's
    spread, the log-loss GP's sample functions' chains to pool and whether the result is
    pooled."""
    final = emulated.final
    if final is not None:
        pooling = settings.pool_functions and final.pooled is not None
        return final.pooled if pooling else final.sample, final.spread, [], pooling
    # the correction's weights judge a corrected posterior and a noise-free one is degenerate
    if corrected is not None or ctx.noise_free or emulated.surrogate is None:
        return corrected, None, [], False
    spread, pooled = _spread_and_pool(ctx, emulated.surrogate, n_eff, settings, rng, emulated.chains,
                                      emulated.ended)
    return corrected, spread, pooled, bool(pooled)


def run_posterior(run_dir: Path | RunDir, settings: PosteriorSettings | None = None,
                  executor: Executor | None = None) -> dict[str, Any]:
    """The whole stage; returns the content of ``posterior/summary.json``.

    Args:
        run_dir: a calibration run directory.
        settings: the stage's settings (default: the project's ``[posterior]`` table).
        executor: where the stage's forward batches run (default: in process).
    """
    start = time.perf_counter()
    ctx = load_run(run_dir, executor)
    settings, out_dir = _begin(ctx, settings if settings is not None else ctx.problem.project.posterior)
    # every step is seeded: a rerun after a kill asks for the same rows and finds them here
    # and the calibration's kept curves of the GP's points, where the curve emulator starts
    ctx.runner.cache = cache = ctx.run.forward_cache("posterior", earlier=ctx.calibration_runs)
    rng = np.random.default_rng(settings.seed)
    calibration_gp, _ = load_surrogate(ctx.run.gp_path)
    # torch and BLAS on one thread: two made the GP fits and the emulators slower (gp_session)
    with ctx.runner, gp_session(), emulator_threads(settings.threads) as threads:
        fit = local_fit(ctx)
        budget = residual_budget(ctx, fit)
        n_eff = budget["n_eff_total"]
        t_emulate = time.perf_counter()
        emulated = _emulate(ctx, calibration_gp, n_eff, settings, rng, out_dir)
        t_correct = time.perf_counter()
        corrected = (correct_posterior(ctx, emulated.chains, n_eff, settings, rng, emulated.data)
                     if settings.correct_draws > 0 else None)
        t_spread = time.perf_counter()
        corrected, spread, pooled, pooling = _reported(ctx, emulated, corrected, n_eff, settings, rng)
        t_outputs = time.perf_counter()
        info = write_outputs(ctx, emulated.emulator, emulated.chains + pooled, budget, settings, rng, out_dir,
                             corrected, fit)
        if spread is not None:
            info["emulator_spread"] = {**spread, "pooled": pooling}
        learning_figures(emulated.active, out_dir)
    cache.close()
    final = emulated.final
    info["stage_seconds"] = {"setup_and_refine": t_emulate - start + emulated.seconds["learning"],
                             "emulator_sampling": emulated.seconds["sampling"],
                             "correction": t_spread - t_correct,
                             "emulator_spread": final.seconds["spread"] if final else t_outputs - t_spread,
                             "outputs": time.perf_counter() - t_outputs}
    info["active_learning"] = {**emulated.active, "start_points": emulated.start_points}
    info["emulator_threads"] = threads
    # the best point's run is the calibration's where it kept its curves
    kept = int(ctx.calibration_runs.holds(ctx.problem.train_ids, ctx.best_theta)[0])
    _count_runs(info["forward_evaluations"], emulated.active["evaluations"], 2 * ctx.space.dim + 1 - kept)
    info["reliability"] = assess(info, ctx.space, ctx.summary.get("best_loss_kN2"), ctx.noise_free,
                                 cheap=ctx.problem.fast)
    info["reliable"] = info["reliability"]["reliable"]
    if not info["reliable"]:
        warnings.warn("the posterior is unreliable: " + "; ".join(info["reliability"]["reasons"]),
                      UnreliablePosteriorWarning, stacklevel=2)
    # parameter sets x configurations: all that shaped the result, those found in the cache
    # (made by an earlier, interrupted or differently set, run) and those made now
    info["simulator_runs"] = ctx.runner.forward_runs
    info["forward_runs_reused"] = ctx.runner.forward_runs_reused
    info["forward_runs_made"] = ctx.runner.forward_runs_made
    info["simulator"] = ctx.summary.get("simulator", "native")
    info["seconds"] = time.perf_counter() - start
    info["settings"] = settings.model_dump(mode="json")
    ctx.run.complete_stage("posterior", info)
    return info
