"""The run directory of a calibration and the files later stages read.

Layout (``RUN_DIR``)::

    config.json          resolved project and calibration settings (the run's identity)
    evaluations.jsonl    append-only log: rounds and evaluations (see runlog)
    summary.json         best loss and parameters, counts, times, settings, stop reason
    best_params.json     best parameter values with units (and which are fixed)
    gp.pt                GP state: torch state_dict + training data (load_surrogate)
    best_curves/<id>.csv simulated curves at the best point, every configuration
    figures/             convergence, best_curves, landscape (2 free parameters); PNG + SVG
    truth-data/          synthetic measured curves of a check with known truth
    work/                work folders of the external-simulator adapter
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from smcbayes.errors import ConfigError
from smcbayes.simulation.executors.base import Executor
from smcbayes.simulation.problem import Problem
from smcbayes.surrogate.design import round_seed
from smcbayes.surrogate.loop import BayesOpt, BOSettings, Progress, training_data
from smcbayes.surrogate.runlog import LOG_NAME, RunLog, write_json

IDENTITY_KEYS = ("project", "effects", "overrides", "fidelity", "external", "seed", "init",
                 "batch", "kernel", "failed", "restarts", "raw_samples", "noise",
                 "local_evaluations", "local_radius", "patience")
"""Settings that must match for ``--resume`` (the budget and tolerance may change)."""


def prepare(run_dir: Path, identity: dict[str, Any], resume: bool) -> None:
    """Create ``run_dir`` or check that a resumed run is the same calibration.

    Raises:
        ConfigError: a run exists without ``--resume``, or ``--resume`` with other settings.
    """
    run_dir.mkdir(parents=True, exist_ok=True)
    cfg = run_dir / "config.json"
    log = run_dir / LOG_NAME
    if not resume and (log.exists() or cfg.exists()):
        raise ConfigError(f"{run_dir}: already holds a calibration run; add --resume to "
                          "continue it or choose another --out")
    clean = json.loads(json.dumps(identity, default=str))
    if resume and cfg.exists():
        old = json.loads(cfg.read_text(encoding="utf-8"))
        for key in IDENTITY_KEYS:
            if old.get(key) != clean.get(key):
                raise ConfigError(f"{run_dir}: --resume with a different '{key}' than the run "
                                  "was started with; use the same config and options")
    write_json(cfg, clean)


def best_params(problem: Problem, record: dict[str, Any]) -> dict[str, dict[str, Any]]:
    """Best values with units, and whether each was fixed."""
    space = problem.model.space
    return {p.name: {"value": record["params"][p.name], "unit": p.unit,
                     "fixed": p.name in space.fixed} for p in space.parameters}


def summary(bo: BayesOpt, problem: Problem, wall_s: float) -> dict[str, Any]:
    """Machine-readable summary of a run (``summary.json``)."""
    best = bo.best()
    evals = [r for _, r in sorted(bo.state.evaluations.items())]
    out: dict[str, Any] = {
        "best_loss_kN2": best["loss"] if best else None,
        "best_index": best["index"] if best else None,
        "best_params": best_params(problem, best) if best else None,
        "best_errors_kN2": best["errors"] if best else None,
        "evaluations": len(evals), "failures": bo.failures(),
        "failure_reasons": [{"index": r["index"], "reason": r["reason"]} for r in evals
                            if r["status"] != "ok"][:50],
        "rounds": len(bo.state.rounds), "stop_reason": bo.stop_reason or "running",
        "seconds_wall": wall_s, "seconds_evaluations": float(sum(r["seconds"] for r in evals)),
        "settings": bo.settings_dict(), "free_parameters": problem.model.space.free_names,
        "fixed_parameters": dict(problem.model.space.fixed), "config_ids": problem.train_ids,
        "effects": list(problem.model.effects.names), "truth": problem.truth,
        "loss": problem.project.loss.model_dump(mode="json"),
    }
    return out


def finish(bo: BayesOpt, problem: Problem, run_dir: Path, wall_s: float,
           figures: bool = True) -> dict[str, Any]:
    """Write the GP state, best parameters and curves, figures and the summary."""
    from smcbayes.commands.common import measured_force, write_curves
    from smcbayes.plotting import plot_simulation
    from smcbayes.surrogate.figures import plot_convergence, plot_landscape
    from smcbayes.surrogate.gp import fit_surrogate, gp_session, save_surrogate

    s = bo.settings
    info = summary(bo, problem, wall_s)
    space = problem.model.space
    x, y = training_data(bo.state, space.to_unit, space.free_names, s.failed)
    surrogate = None
    seed = round_seed(s.seed, len(bo.state.rounds))
    if x.shape[0] >= 2 and np.ptp(y) > 0:
        with gp_session():
            surrogate = fit_surrogate(x, y, s.kernel, seed, s.noise)
        save_surrogate(run_dir / "gp.pt", surrogate, {
            "free_parameters": space.free_names, "fixed": dict(space.fixed),
            "lower": [p.lower for p in space.free], "upper": [p.upper for p in space.free],
            "log": [p.log for p in space.free], "config_ids": problem.train_ids,
            "effects": list(problem.model.effects.names)})
    best = bo.best()
    fig_dir = run_dir / "figures"
    if best is not None:
        write_json(run_dir / "best_params.json", best_params(problem, best))
        ids = problem.model.config_ids
        results = problem.model.simulate_params({k: np.array([v]) for k, v in best["params"].items()}, ids)
        (run_dir / "best_curves").mkdir(exist_ok=True)
        for cid, res in results.items():
            write_curves(res, 0, run_dir / "best_curves" / f"{cid}.csv")
        if figures:
            label = ", ".join(f"{k}={v:.4g}" for k, v in best["params"].items())
            plot_simulation(results, measured_force(problem.project, ids), fig_dir / "best_curves",
                            f"best point (loss {best['loss']:.4g} kN$^2$): {label}")
    if figures:
        plot_convergence(bo.losses(), s.init, fig_dir / "convergence")
        if surrogate is not None and space.dim == 2:
            from smcbayes.surrogate.acquisition import propose

            recs = [r for _, r in sorted(bo.state.evaluations.items())]
            with gp_session():
                cand, _ = propose(surrogate, 1, seed, s.restarts, s.raw_samples)
                plot_landscape(surrogate, space, recs, s.init, cand, problem.truth,
                               fig_dir / "landscape")
    write_json(run_dir / "summary.json", info)
    return info


def print_progress(p: Progress) -> None:
    """One terminal line per finished evaluation (overwritten in place on a terminal)."""
    import sys

    best = f"{p.best_loss:.5g}" if math.isfinite(p.best_loss) else "-"
    remaining = f"{p.remaining_s:.0f}" if math.isfinite(p.remaining_s) else "?"
    line = (f"[{p.done:>4}/{p.budget}] best loss {best} kN^2  failures {p.failures}  "
            f"elapsed {p.elapsed_s:.0f} s  remaining ~{remaining} s")
    end = "\r" if sys.stderr.isatty() and p.done < p.budget else "\n"
    print(line, end=end, file=sys.stderr, flush=True)


def calibrate(problem: Problem, settings: BOSettings, run_dir: Path, executor: Executor,
              figures: bool = True,
              progress: Callable[[Progress], None] | None = print_progress) -> dict[str, Any]:
    """Run (or resume) a calibration in ``run_dir`` (checked by :func:`prepare`); returns the summary."""
    start = time.perf_counter()

    def on_round(bo: BayesOpt) -> None:
        write_json(run_dir / "summary.json", summary(bo, problem, time.perf_counter() - start))

    bo = BayesOpt(problem.objective, settings, RunLog(run_dir / LOG_NAME), executor,
                  on_progress=progress, on_round=on_round)
    bo.run()
    return finish(bo, problem, run_dir, time.perf_counter() - start, figures)
