"""What the posterior stage takes from a calibration run, and its forward runs.

:func:`load_run` reads the run directory (identity, calibration summary, the problem with
its simulator and data) without simulating anything; every forward run the stage makes
afterwards (likelihood, sensitivities, correction, emulator check, bands) goes through
the run's :class:`~smcbayes.simulation.runner.Runner`, so an external simulator serves the
posterior exactly as it served the calibration, on the same executor, and the runs are
counted.
"""

from __future__ import annotations

import functools
import json
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from smcbayes.config import ProjectConfig
from smcbayes.forward.parameters import ParameterSpace
from smcbayes.forward.result import SimulationResult
from smcbayes.run import RunDir
from smcbayes.run.cache import ForwardCache
from smcbayes.simulation.executors.base import Executor
from smcbayes.simulation.problem import Problem
from smcbayes.simulation.runner import Runner
from smcbayes.surrogate.loop import search_points

Array = NDArray[np.float64]


@dataclass
class RunContext:
    """What the posterior needs from a calibration run.

    Attributes:
        run: the run directory.
        problem: the calibration problem (simulator, data, loss, parameter space).
        summary: the calibration summary.
        best_theta: best calibrated free parameters ``(1, d)`` (user units).
        runner: the run's simulator on the stage's executor; counts the forward runs.
    """

    run: RunDir
    problem: Problem
    summary: dict[str, Any]
    best_theta: Array
    runner: Runner

    @property
    def noise_free(self) -> bool:
        """Whether the training curves are simulator output without noise: a truth check
        (``[calibration] truth``, whose curves are written noiseless) or an
        ``smcbayes synth`` dataset whose truth.json records every noise term as 0."""
        project = self.problem.project
        if project.calibration.truth is not None:
            return True
        root = project.data_path()
        path = None if root is None else root / "truth.json"
        if path is None or not path.is_file():
            return False
        noise = json.loads(path.read_text(encoding="utf-8")).get("noise")
        force_noise = ("white_kN", "correlated_kN", "resolution_kN")
        return bool(noise) and all(float(noise.get(k, 0.0)) == 0.0 for k in force_noise)

    @property
    def run_dir(self) -> Path:
        """The run directory's path."""
        return self.run.root

    @functools.cached_property
    def calibration_runs(self) -> ForwardCache:
        """The calibration's forward-run cache, read only: the curves of the GP's points."""
        return self.run.calibration_cache(read_only=True)

    @functools.cached_property
    def stale_calibration_runs(self) -> str | None:
        """A warning when the external simulator's files changed since the calibration, or
        the calibration kept forward runs of another model only (the package, its model code
        or the run's model changed since): none of them is reused, and the GP and best
        point the stage starts from describe that model; ``None`` otherwise.  Read once, at
        the stage's start, so that its warning and its summary say the same."""
        changed = self.run.changed_external_files()
        cache = self.calibration_runs
        if not changed and (len(cache) or not cache.other_models()):
            return None
        why = (f"the external simulator's file(s) {', '.join(changed)} changed since the calibration"
               if changed else "the package, its model code or the run's model changed since the "
               "calibration")
        return (f"the calibration's forward runs ({cache.folder}) are of another model ({why}): "
                "none is reused, and the calibration's GP and best point, where this stage "
                "starts, describe that model; to start from the present one, calibrate again "
                "with another --out")

    @property
    def space(self) -> ParameterSpace:
        """The parameter space."""
        return self.problem.space


def load_run(run_dir: Path | RunDir, executor: Executor | None = None) -> RunContext:
    """Read a calibration run (nothing is simulated); ``executor`` runs the stage's forward
    batches (in process when ``None``)."""
    run = run_dir if isinstance(run_dir, RunDir) else RunDir(run_dir)
    run.require()
    problem = run.load_problem()
    summary = run.calibration_summary() or {}
    theta = run.best_theta(problem.space.free_names)
    if problem.truth is None:
        problem.truth = synthetic_truth(problem.project, problem.space.defaults())
    retries = run.identity().settings.get("retries")  # as calibrated, not the project's current table
    return RunContext(run, problem, summary, theta, problem.runner(executor, retries))


def synthetic_truth(project: ProjectConfig, defaults: dict[str, float]) -> dict[str, float] | None:
    """True parameters of a dataset written by ``smcbayes synth`` (its truth.json), if any."""
    root = project.data_path()
    path = None if root is None else root / "truth.json"
    if path is None or not path.is_file():
        return None
    params = json.loads(path.read_text(encoding="utf-8")).get("parameters", {})
    return {**defaults, **{k: float(v) for k, v in params.items() if k in defaults}}


def true_log_loss(ctx: RunContext, theta: Array) -> Array:
    """log of the global loss from the run's simulator at ``theta`` ``(P, d)``; NaN if failed."""
    loss = ctx.runner.loss(theta)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(loss > 0, np.log(loss), np.nan)


def exact_log_posterior(ctx: RunContext, n_eff: float) -> Callable[[Array], Array]:
    """Exact unnormalised log posterior on the unit cube, ``(P, d) -> (P,)``: one batched
    forward run of the training configurations, -(N_eff / 2) log L (NaN where it failed)."""
    a = 0.5 * n_eff

    def log_post(u: Array) -> Array:
        return -a * true_log_loss(ctx, ctx.space.from_unit(np.atleast_2d(u)))

    return log_post


SEARCH_SPACING = 0.01
"""Least distance (unit cube) between the local search's evaluations that join the emulator's
first training set: closer ones add ill-conditioning, not information."""

SEARCH_POINTS = 400
"""At most this many of the local search's evaluations join it (the best): a search run with
a large budget must not push the GP past the size its exact solves handle quickly."""


def emulator_start(ctx: RunContext, x_unit: Array, log_loss: Array, spacing: float = SEARCH_SPACING,
                   limit: int = SEARCH_POINTS) -> tuple[Array, Array]:
    """The emulator's first training set: the calibration GP's ``x_unit`` ``(N, d)`` (unit
    cube) and ``log_loss`` ``(N,)`` (log of the loss, kN^2) followed by up to ``limit`` of the
    calibration's local-search evaluations (Powell's line searches,
    :mod:`smcbayes.surrogate.polish`), which the calibration GP thins to their best;
    returns ``(N + M, d)`` and ``(N + M,)``.

    Those evaluations lie on the valley floor around the calibrated point, where the
    posterior lives; without them the emulator starts from the few dozen points of the
    Bayesian optimisation, of which a handful lie within the posterior's log-likelihood
    range.  They are taken best first, each kept at least ``spacing`` from every point
    already in the set.  Runs without a local search return the inputs themselves.
    """
    x_new, y_new = search_points(ctx.run.evaluation_log().read(), ctx.space.to_unit, ctx.space.free_names)
    if not y_new.size:
        return x_unit, log_loss
    n = log_loss.size
    x = np.empty((n + min(limit, y_new.size), x_unit.shape[1]))
    y = np.empty(x.shape[0])
    x[:n], y[:n] = x_unit, log_loss
    k = n
    for i in np.argsort(y_new, kind="stable"):
        if k == x.shape[0]:
            break
        if k == 0 or np.min(np.linalg.norm(x[:k] - x_new[i], axis=1)) >= spacing:
            x[k], y[k] = x_new[i], y_new[i]
            k += 1
    return x[:k], y[:k]


LOGGED_MATCH = 1e-9
"""Largest difference (unit cube) at which a GP training point is the logged evaluation."""


def logged_rows(ctx: RunContext, x_unit: Array) -> Array:
    """The free parameters ``(N, d)`` (user units) of the calibration's evaluations at the
    unit-cube points ``x_unit`` ``(N, d)`` (the GP's training points), exactly as the log
    holds them where it holds one within :data:`LOGGED_MATCH` of a point, else the point
    mapped back.  The round trip through the unit cube can change a value's last bit, and
    the calibration's kept runs are found by their exact rows."""
    x_unit = np.atleast_2d(np.asarray(x_unit, dtype=float))
    theta = ctx.space.from_unit(x_unit)
    names = ctx.space.free_names
    recs = [r for r in ctx.run.evaluation_log().read().evaluations.values()
            if isinstance(r.get("params"), dict)]
    if not recs or not x_unit.size:
        return theta
    logged = np.array([[r["params"][n] for n in names] for r in recs], dtype=float)
    unit = ctx.space.to_unit(logged)
    for k, u in enumerate(x_unit):
        gap = np.max(np.abs(unit - u), axis=1)
        j = int(np.argmin(gap))
        if gap[j] <= LOGGED_MATCH:
            theta[k] = logged[j]
    return theta


def start_curves(ctx: RunContext, x_unit: Array, ids: Sequence[str]
                 ) -> tuple[dict[str, SimulationResult], int, int]:
    """The curves of the GP's points ``x_unit`` ``(N, d)`` (unit cube) on ``ids``, run at
    their logged rows (:func:`logged_rows`): the calibration's where it kept them
    (:attr:`RunContext.calibration_runs`), else simulated.

    Returns:
        The curves (``N`` rows per configuration), how many of the points the calibration
        kept, and how many the stage ran for them: the others but the best point, which
        the sensitivities ran (and count) at the same row before.
    """
    theta = logged_rows(ctx, x_unit)
    kept = ctx.calibration_runs.holds(ids, theta)
    best = np.all(theta == ctx.best_theta, axis=1)
    results = ctx.runner.simulate(theta, ids)
    return results, int(np.count_nonzero(kept)), int(np.count_nonzero(~kept & ~best))
