"""The thesis's 2-D check and the local process pool on the real forward model."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from smcbayes.config import load_project
from smcbayes.surrogate.executors.local import LocalExecutor
from smcbayes.surrogate.loop import BayesOpt, BOSettings
from smcbayes.surrogate.problem import build_problem
from smcbayes.surrogate.runlog import RunLog

ROOT = Path(__file__).resolve().parents[2]
CONFIG = ROOT / "configs" / "verify-slip-2d.toml"


def settings(project, **kw) -> BOSettings:  # noqa: ANN001
    c = project.calibration
    base = dict(budget=c.budget, init=c.init, batch=c.batch, kernel=c.kernel, seed=c.seed,
                local_evaluations=c.local_evaluations, local_radius=c.local_radius)
    return BOSettings(**{**base, **kw})


def test_slip_2d_recovers_truth(tmp_path: Path) -> None:
    """5 LHS + 25 BO evaluations: best within 2 % of the range of the truth in both parameters."""
    project = load_project(CONFIG)
    problem = build_problem(project, tmp_path)
    s = settings(project, seed=2)
    assert (s.init, s.budget) == (5, 30)
    bo = BayesOpt(problem.objective, s, RunLog(tmp_path / "log.jsonl"), LocalExecutor(1)).run()
    best = bo.best()["params"]
    assert best["n"] == 0.4 and best["B_Pa_s"] == 1e4  # fixed parameters stay fixed
    err_log_tau = abs(np.log10(best["tau_c_MPa"]) - np.log10(0.01)) / (np.log10(1.0) - np.log10(0.005))
    err_m = abs(best["m"] - 1.5) / (1.9 - 1.0)
    assert err_log_tau <= 0.02 and err_m <= 0.02


def test_process_pool_equals_inline(tmp_path: Path) -> None:
    project = load_project(CONFIG)
    problem = build_problem(project, tmp_path)
    s = settings(project, budget=6, init=4, batch=2)
    runs = []
    for workers in (1, 2):
        log = RunLog(tmp_path / f"log{workers}.jsonl")
        bo = BayesOpt(problem.objective, s, log, LocalExecutor(workers)).run()
        runs.append([{k: v for k, v in r.items() if k != "seconds"}
                     for _, r in sorted(bo.state.evaluations.items())])
    assert runs[0] == runs[1] and len(runs[0]) == 6
    assert all(r["status"] == "ok" for r in runs[0])
