"""The diagnosis context of a calibration run directory (read, nothing simulated)."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from smcbayes.diagnose.fit import DiagnosisContext
from smcbayes.errors import ConfigError
from smcbayes.posterior.context import synthetic_truth
from smcbayes.run import RunDir
from smcbayes.simulation.executors.base import Executor


def context_from_run(run_dir: Path | RunDir,
                     executor: Callable[[], Executor] | None = None) -> DiagnosisContext:
    """Project, data, effects and the calibrated optimum of ``run_dir``; ``executor`` makes
    the executor of each model's forward batches (default: in process)."""
    run = run_dir if isinstance(run_dir, RunDir) else RunDir(run_dir)
    run.require()
    identity = run.identity()
    if identity.external:
        raise ConfigError(f"{run.root}: the run used an external simulator; the diagnosis switches "
                          "effects of the native forward model and cannot use it")
    problem = run.load_problem()
    theta = run.best_theta(problem.space.free_names)
    batch = problem.space.batch(theta)
    truth = problem.truth or synthetic_truth(problem.project, problem.space.defaults())
    return DiagnosisContext(
        project=problem.project, dataset=problem.dataset, ids=list(problem.train_ids),
        base_effects=tuple(problem.model.effects.names), overrides=dict(identity.overrides),
        fidelity=identity.fidelity, base_params={k: float(v[0]) for k, v in batch.items()}, truth=truth,
        executor=executor, run=run)
