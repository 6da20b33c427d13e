"""The calibration stage: run (or resume) the Bayesian optimisation in a run directory.

Writes, through :class:`~smcbayes.run.RunDir`: the evaluation log (as it goes), the summary
after every round, and at the end the GP state, the best parameters, the simulated curves
at the best point on every configuration (with the validation errors, so that later
stages and the report need not simulate again) and the figures.
"""

from __future__ import annotations

import logging
import math
import time
import warnings
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from smcbayes.config import CalibrationSpec
from smcbayes.data.loss import contact_beyond_bound, contact_offsets_mm, mixed_force_pair
from smcbayes.data.readers.csv import write_curves
from smcbayes.errors import ContactOffsetWarning, ParameterOnBoundWarning
from smcbayes.forward.ranges import PHYSICAL_RANGES
from smcbayes.forward.result import SimulationResult
from smcbayes.plotting import plot_simulation
from smcbayes.progress import Progress as ProgressBar
from smcbayes.run import RunDir
from smcbayes.simulation.executors.base import Executor
from smcbayes.simulation.problem import Problem
from smcbayes.surrogate.acquisition import propose
from smcbayes.surrogate.design import round_seed
from smcbayes.surrogate.figures import plot_convergence, plot_landscape
from smcbayes.surrogate.gp import fit_surrogate, gp_session, save_surrogate
from smcbayes.surrogate.loop import BayesOpt, Progress, thin_polish, training_data
from smcbayes.surrogate.polish import is_search

logger = logging.getLogger(__name__)

BOUND_SHARE = 0.01
"""A calibrated value within this share of the search range (unit cube) of a bound is
reported as lying on it."""


def best_params(problem: Problem, record: dict[str, Any]) -> dict[str, dict[str, Any]]:
    """Best values with units, and whether each was fixed."""
    space = problem.space
    return {p.name: {"value": record["params"][p.name], "unit": p.unit,
                     "fixed": p.name in space.fixed} for p in space.parameters}


def search_box(problem: Problem) -> dict[str, dict[str, Any]]:
    """Search bounds of the free parameters (user units) and whether searched in log10."""
    return {p.name: {"lower": p.lower, "upper": p.upper, "log": p.log, "unit": p.unit}
            for p in problem.space.free}


def on_bounds(problem: Problem, params: dict[str, float]) -> list[dict[str, Any]]:
    """Free parameters within :data:`BOUND_SHARE` of a search bound (in unit-cube terms)."""
    space = problem.space
    theta = np.array([[params[n] for n in space.free_names]])
    unit = space.to_unit(theta)[0]
    out = []
    for p, u in zip(space.free, unit, strict=True):
        if u <= BOUND_SHARE or u >= 1.0 - BOUND_SHARE:
            side = "lower" if u <= BOUND_SHARE else "upper"
            limit = p.lower if side == "lower" else p.upper
            known = PHYSICAL_RANGES.get(p.name)
            physical = None if known is None else (known.lower if side == "lower" else known.upper)
            out.append({"name": p.name, "bound": side, "value": params[p.name], "limit": limit,
                        "unit": p.unit, "physical_limit": physical,
                        "advice": ParameterOnBoundWarning.advice(p.name, side, limit, params[p.name],
                                                                 physical)})
    return out


def summary(bo: BayesOpt, problem: Problem, wall_s: float) -> dict[str, Any]:
    """Machine-readable summary of a run (``summary.json``)."""
    best = bo.best()
    evals = [r for _, r in sorted(bo.state.evaluations.items())]
    space = problem.space
    return {
        "best_loss_kN2": best["loss"] if best else None,
        "best_index": best["index"] if best else None,
        "best_params": best_params(problem, best) if best else None,
        "best_errors_kN2": best["errors"] if best else None,
        "evaluations": len(evals), "failures": bo.failures(),
        "failure_reasons": [{"index": r["index"], "reason": r["reason"]} for r in evals
                            if r["status"] != "ok"][:50],
        "rounds": len(bo.state.rounds), "stop_reason": bo.stop_reason or "running",
        "seconds_wall": wall_s, "seconds_evaluations": float(sum(r["seconds"] for r in evals)),
        "settings": {**bo.settings_dict(), "polish": bo.polish_budget},
        "polish": bo.polish.as_dict() if bo.polish is not None else None,
        "free_parameters": space.free_names,
        "fixed_parameters": dict(space.fixed), "search_box": search_box(problem),
        "config_ids": problem.train_ids, "validation_ids": problem.model.ids("validation"),
        "effects": list(problem.model.effects.names), "truth": problem.truth,
        "simulator": "external" if problem.simulator is not problem.model else "native",
        "loss": problem.project.loss.model_dump(mode="json"),
        "on_bounds": on_bounds(problem, best["params"]) if best else [],
    }


def _save_gp(bo: BayesOpt, problem: Problem, run: RunDir) -> Any:
    """Fit the final GP to every evaluation and save it; ``None`` with too little data."""
    s, space = bo.settings, problem.space
    x, y = training_data(bo.state, space.to_unit, space.free_names, s.failed)
    if x.shape[0] < 2 or not np.ptp(y) > 0:
        return None
    with gp_session():
        surrogate = fit_surrogate(x, y, s.kernel, round_seed(s.seed, len(bo.state.rounds)), s.noise_variance)
    save_surrogate(run.gp_path, surrogate, {
        "free_parameters": space.free_names, "fixed": dict(space.fixed),
        "lower": [p.lower for p in space.free], "upper": [p.upper for p in space.free],
        "log": [p.log for p in space.free], "config_ids": problem.train_ids,
        "effects": list(problem.model.effects.names)})
    return surrogate


def validation_errors(problem: Problem, results: dict[str, SimulationResult],
                      offsets_mm: Sequence[float] = ()) -> dict[str, dict[str, float]]:
    """Force MSE (kN^2) and RMSE (kN) of the best point on validation configurations with
    data, each judged by its curve averaged over the training trials' contact offsets
    ``offsets_mm`` (mm; a validation trial's own is not fitted,
    :func:`~smcbayes.data.loss.mixed_force_pair`); at the nominal contact without any."""

    ids = [cid for cid in problem.model.ids("validation") if cid in problem.dataset.measurements
           and problem.dataset.measurements[cid].force is not None and cid in results]
    out = {}
    for cid in ids:
        pair = mixed_force_pair(results[cid], problem.dataset.measurements[cid], problem.project.loss,
                                offsets_mm)
        mse = float(np.mean((pair.sim_kN[0] - pair.meas_kN[0]) ** 2)) if bool(pair.ok[0]) else float("nan")
        out[cid] = {"mse_kN2": mse, "rmse_kN": math.sqrt(mse) if math.isfinite(mse) else float("nan")}
    return out


def _best_outputs(bo: BayesOpt, problem: Problem, run: RunDir, executor: Executor | None,
                  figures: bool) -> dict[str, Any]:
    """Best parameters, their curves on every configuration (through the run's simulator)
    and the validation errors; returns the extra summary fields."""
    best = bo.best()
    if best is None:
        return {}
    run.write_best_params(best_params(problem, best))
    ids = problem.model.config_ids
    theta = np.array([[best["params"][n] for n in problem.space.free_names]])
    with problem.runner(executor) as runner:
        results = runner.simulate(theta, ids)
    for cid, res in results.items():
        path = run.best_curves_path(cid)
        path.parent.mkdir(exist_ok=True)
        write_curves(res, 0, path)
    offsets = contact_offsets_mm(results, problem.dataset, problem.project.loss, problem.train_ids)
    if figures:
        label = ", ".join(f"{k}={v:.4g}" for k, v in best["params"].items())
        speed = {c: problem.project.get(c).press.speed_mm_s for c in ids}
        # a trial with its own offset is drawn at it, one without as its mean over theirs
        delays = {c: o / speed[c] for c, o in offsets.items()} if offsets else None
        mixed = ({c: [o / speed[c] for o in offsets.values()] for c in ids if c not in offsets}
                 if offsets else None)
        plot_simulation(results, problem.measured_force(ids), run.figures / "best_curves",
                        f"best point (loss {best['loss']:.4g} kN$^2$): {label}", delays_s=delays,
                        mixed_delays_s=mixed)
    out: dict[str, Any] = {"validation_errors": validation_errors(problem, results, list(offsets.values()))}
    if offsets:
        out["contact_offsets_mm"] = offsets
    beyond = contact_beyond_bound(results, problem.dataset, problem.project.loss, problem.train_ids)
    if beyond:
        bound = problem.project.loss.contact_offset_mm
        out["contact_on_bound"] = [{"config_id": c, "offset_mm": v, "bound_mm": bound,
                                    "advice": ContactOffsetWarning.advice(c, v, bound)}
                                   for c, v in beyond.items()]
    return out


def warn_on_bounds(info: dict[str, Any]) -> None:
    """One :class:`ParameterOnBoundWarning` per calibrated parameter on a search bound, one
    :class:`ContactOffsetWarning` per trial whose end state puts its contact beyond the
    bound of the loss."""
    for b in info.get("on_bounds") or []:
        text = b.get("advice") or ParameterOnBoundWarning.advice(b["name"], b["bound"], b["limit"],
                                                                  b["value"])
        warnings.warn(text, ParameterOnBoundWarning, stacklevel=3)
    for c in info.get("contact_on_bound") or []:
        warnings.warn(c["advice"], ContactOffsetWarning, stacklevel=3)


def finish(bo: BayesOpt, problem: Problem, run: RunDir, wall_s: float, figures: bool = True,
           executor: Executor | None = None) -> dict[str, Any]:
    """Write the GP state, best parameters and curves, figures and the summary."""
    info = summary(bo, problem, wall_s)
    surrogate = _save_gp(bo, problem, run)
    info.update(_best_outputs(bo, problem, run, executor, figures))
    if figures:
        s = bo.settings
        local = np.array([is_search(bo.state, r["round"]) for _, r in sorted(bo.state.evaluations.items())],
                         dtype=bool)
        plot_convergence(bo.losses(), s.init, run.figures / "convergence", local)
        if surrogate is not None and problem.space.dim == 2:
            # a local search's line searches would hide the path: its best point stands for it
            recs = thin_polish([r for _, r in sorted(bo.state.evaluations.items())], bo.state)
            with gp_session():
                cand, _ = propose(surrogate, 1, round_seed(s.seed, len(bo.state.rounds)), s.restarts,
                                  s.raw_samples)
                plot_landscape(surrogate, problem.space, recs, s.init, cand, problem.truth,
                               run.figures / "landscape")
    run.write_calibration_summary(info)
    warn_on_bounds(info)
    return info


def progress_reporter(budget: int) -> Callable[[Progress], None]:
    """A loop callback that feeds :class:`smcbayes.progress.Progress` (one update per evaluation)."""
    bar = ProgressBar(budget, "calibration", unit="eval")
    seen, closed = [0], [False]

    def report(p: Progress) -> None:
        if closed[0]:
            return
        if p.budget != bar.total:  # a local search that converged early, a resumed run
            bar.set_total(p.budget)
        new = max(p.done - seen[0], 0)
        seen[0] = p.done
        finished = p.done >= p.budget
        if new or finished:
            best = f"best {p.best_loss:.5g} kN^2" if math.isfinite(p.best_loss) else "best -"
            bar.update(new, note=f"{best}, {p.failures} failed")
        if finished:
            bar.close()
            closed[0] = True

    return report


def calibrate(problem: Problem, settings: CalibrationSpec, run_dir: RunDir | Path, executor: Executor,
              figures: bool = True,
              progress: Callable[[Progress], None] | None = None) -> dict[str, Any]:
    """Run (or resume) a calibration in ``run_dir`` (prepared by :meth:`RunDir.prepare`).

    Args:
        problem: the calibration problem (simulator, data, loss).
        settings: the ``[calibration]`` settings.
        run_dir: the run directory.
        executor: where evaluations run.
        figures: write the figures.
        progress: called after every evaluation (default: :func:`progress_reporter`).

    Returns:
        The summary (``summary.json``).
    """
    run = run_dir if isinstance(run_dir, RunDir) else RunDir(run_dir)
    settings.check()
    start = time.perf_counter()

    def on_round(bo: BayesOpt) -> None:
        run.write_calibration_summary(summary(bo, problem, time.perf_counter() - start))

    polish = settings.polish_evaluations(problem.fast)
    # the GP's points keep their curves, so the posterior's curve emulator starts from them
    # without simulating them again; the cache is tied to the run's identity, which a folder
    # not prepared as a run directory lacks
    cache = run.calibration_cache() if run.is_run() else None
    bo = BayesOpt(problem.objective, settings, run.evaluation_log(), executor,
                  on_progress=progress or progress_reporter(settings.budget + polish), on_round=on_round,
                  polish=polish, cache=cache)
    try:
        bo.run()
    finally:
        if cache is not None:
            cache.close()
    logger.info("calibration stopped: %s", bo.stop_reason)
    return finish(bo, problem, run, time.perf_counter() - start, figures, executor)
