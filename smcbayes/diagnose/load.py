"""The diagnosis context of a calibration run directory."""

from __future__ import annotations

import json
from pathlib import Path

from smcbayes.diagnose.fit import DiagnosisContext
from smcbayes.errors import ConfigError


def context_from_run(run_dir: Path) -> DiagnosisContext:
    """Rebuild project, data, effects and the calibrated optimum of ``run_dir``."""
    from smcbayes.posterior.stage import load_run

    if not run_dir.is_dir():
        raise ConfigError(f"{run_dir}: run directory not found; pass the --out folder of "
                          "`smcbayes calibrate`")
    run = load_run(run_dir)
    identity = json.loads((run_dir / "config.json").read_text(encoding="utf-8"))
    problem = run.problem
    if identity.get("external"):
        raise ConfigError(f"{run_dir}: the run used an external simulator; the diagnosis needs "
                          "the native forward model with its effects")
    batch = problem.model.space.batch(run.best_theta)
    params = {k: float(v[0]) for k, v in batch.items()}
    return DiagnosisContext(
        project=problem.project, dataset=problem.objective.dataset, ids=list(problem.train_ids),
        base_effects=tuple(problem.model.effects.names),
        overrides=dict(identity.get("overrides") or {}), fidelity=identity.get("fidelity"),
        base_params=params, truth=problem.truth)
